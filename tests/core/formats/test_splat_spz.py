"""antimatter15 `.splat` and Niantic `.spz` readers and writers.

Layouts are pinned by files assembled here byte by byte with `struct` (never with the modules'
own encoders); round trips are held to the quantisation bounds documented in each module; re-saving
what was loaded must reproduce the quantised data bit for bit.
"""

from __future__ import annotations

import gzip
import math
import struct
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from addon.core import splat_io
from addon.core.formats import splat, spz
from addon.core.formats_common.errors import SplatFileError
from addon.core.gaussians import Gaussians

SH_C0 = 0.28209479177387814
CHAIR_COUNT = 89_945
BIKER_COUNT = 152_746


def sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-x.astype(np.float64)))


def unit(q: np.ndarray) -> np.ndarray:
    q = q.astype(np.float64)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def aligned(q: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """`q` with each row's sign chosen to match `reference` (q and -q are one rotation)."""
    return q * np.where(np.sum(q * reference, axis=1, keepdims=True) < 0, -1.0, 1.0)


def random_gaussians(rng: np.random.Generator, n: int, degree: int, extent: float = 50.0) -> Gaussians:
    """Gaussians with every quantity inside the SPZ and .splat ranges."""
    k = (degree + 1) ** 2
    sh = rng.uniform(-0.85, 0.85, (n, k, 3))  # SPZ's default 4-bit SH range tops out at 0.875
    sh[:, 0, :] = rng.uniform(-1.7, 1.7, (n, 3))  # DC colours inside [0, 1]
    quats = rng.normal(size=(n, 4)) * rng.uniform(0.1, 10.0, (n, 1))  # any scale: normalised on use
    return Gaussians(rng.uniform(-extent, extent, (n, 3)), rng.uniform(-9.9, 5.9, (n, 3)), quats,
                     rng.normal(0.0, 3.0, n), sh)


def first_line(error: pytest.ExceptionInfo) -> str:
    return str(error.value)


# ------------------------------------------------------------------------------------------
# Hand-assembled SPZ files (independent of spz.py's writer)


def zstd_frame(data: bytes) -> bytes:
    import zstandard
    return zstandard.ZstdCompressor(level=3).compress(data)


def spz_file(version: int, n: int, sh_degree: int, streams: list[bytes], *, fractional_bits: int = 12,
             flags: int = 0, extensions: bytes = b"", num_points: int | None = None) -> bytes:
    """An SPZ file of the given attribute streams: gzip (v2, v3) or the v4 NGSP container."""
    count = n if num_points is None else num_points
    if version < 4:
        header = struct.pack("<4sIIBBBB", b"NGSP", version, count, sh_degree, fractional_bits, flags, 0)
        return gzip.compress(header + b"".join(streams) + extensions)
    frames = [(zstd_frame(s), len(s)) for s in streams if s]
    toc_offset = 32 + len(extensions)
    header = struct.pack("<4sIIBBBBI12s", b"NGSP", version, count, sh_degree, fractional_bits, flags,
                         len(frames), toc_offset, bytes(12))
    toc = b"".join(struct.pack("<QQ", len(f), size) for f, size in frames)
    return header + extensions + toc + b"".join(f for f, _ in frames)


def fixed24(value: int) -> bytes:
    return struct.pack("<i", value)[:3]


# One Gaussian, stored in RUB: position (1, 2, -1) with 12 fractional bits; a 60 degree turn about
# y whose stored code leaves out w; colour codes 200, 127, 0; alpha 255; log scales 0, 1, -10;
# degree-1 SH codes R of coefficient 0 = 192 (+0.5), G of coefficient 1 = 64 (-0.5),
# B of coefficient 2 = 160 (+0.25).
HAND_POSITION = fixed24(4096) + fixed24(8192) + fixed24(-4096)
HAND_ALPHA = bytes([255])
HAND_COLORS = bytes([200, 127, 0])
HAND_SCALES = bytes([160, 176, 0])
HAND_ROTATION_V3 = struct.pack("<I", (3 << 30) | (0 << 20) | (361 << 10) | 0)
HAND_ROTATION_V2 = bytes([128, 191, 128])  # x = 0.0039, y = 0.498, z = 0.0039, w derived
HAND_SH = bytes([192, 128, 128, 128, 64, 128, 128, 128, 160])


def hand_streams(version: int) -> list[bytes]:
    rotation = HAND_ROTATION_V3 if version >= 3 else HAND_ROTATION_V2
    return [HAND_POSITION, HAND_ALPHA, HAND_COLORS, HAND_SCALES, rotation, HAND_SH]


def check_hand_gaussian(g: Gaussians, version: int, rdf_stored: bool = False) -> None:
    assert len(g) == 1 and g.degree == 1
    flip = np.array([1.0, 1.0, 1.0]) if rdf_stored else np.array([1.0, -1.0, -1.0])
    np.testing.assert_array_equal(g.means[0], np.array([1.0, 2.0, -1.0]) * flip)
    np.testing.assert_array_equal(g.log_scales[0], [0.0, 1.0, -10.0])
    np.testing.assert_allclose(g.sh[0, 0], (np.array([200, 127, 0]) / 255 - 0.5) / 0.15, rtol=1e-6)
    assert sigmoid(g.opacity_logits)[0] == pytest.approx(1 - 0.25 / 255, abs=1e-7)
    if version >= 3:
        y = math.sqrt(0.5) * 361 / 511
        xyzw = np.array([0.0, y, 0.0, math.sqrt(1 - y * y)])
    else:
        x, y, z = np.array([128, 191, 128]) / 127.5 - 1
        xyzw = np.array([x, y, z, math.sqrt(1 - x * x - y * y - z * z)])
    wxyz = xyzw[[3, 0, 1, 2]] * np.array([1.0, flip[1] * flip[2], flip[0] * flip[2], flip[0] * flip[1]])
    np.testing.assert_allclose(g.quats[0], wxyz, atol=1e-7)
    # SH signs under RUB -> RDF: coefficient 0 (odd in y) and 1 (odd in z) flip, 2 (odd in x) not.
    sh_sign = np.array([1.0, 1.0, 1.0]) if rdf_stored else np.array([-1.0, -1.0, 1.0])
    expected = np.zeros((3, 3))
    expected[0, 0], expected[1, 1], expected[2, 2] = 0.5, -0.5, 0.25
    np.testing.assert_allclose(g.sh[0, 1:], expected * sh_sign[:, None], atol=1e-7)


@pytest.mark.parametrize("version", [2, 3, 4])
def test_spz_hand_assembled_layout(tmp_path: Path, version: int) -> None:
    path = tmp_path / f"hand{version}.spz"
    path.write_bytes(spz_file(version, 1, 1, hand_streams(version)))
    check_hand_gaussian(spz.load(path), version)
    packed = spz.read_packed(path)
    assert (packed.version, packed.sh_degree, packed.fractional_bits) == (version, 1, 12)


def test_spz_uncompressed_legacy_stream_is_read(tmp_path: Path) -> None:
    """Some tools write a v2/v3 stream without the gzip wrapper; Niantic's own reader refuses,
    but the stream is unambiguous."""
    path = tmp_path / "plain.spz"
    path.write_bytes(gzip.decompress(spz_file(3, 1, 1, hand_streams(3))))
    check_hand_gaussian(spz.load(path), 3)


def test_spz_extensions(tmp_path: Path) -> None:
    unknown = struct.pack("<II", 0x12340001, 5) + b"hello"
    rdf = struct.pack("<III", 0xADBE0003, 4, 6)  # SPZ_ADOBE_coordinate_system: RDF
    for version in (3, 4):  # legacy: records after the arrays; v4: between header and TOC
        path = tmp_path / f"ext{version}.spz"
        path.write_bytes(spz_file(version, 1, 1, hand_streams(version), flags=0x2,
                                  extensions=unknown + rdf))
        check_hand_gaussian(spz.load(path), version, rdf_stored=True)
        path.write_bytes(spz_file(version, 1, 1, hand_streams(version), flags=0x2, extensions=unknown))
        check_hand_gaussian(spz.load(path), version)  # unknown record skipped, RUB assumed
    rotated = struct.pack("<III", 0xADBE0003, 4, 14)  # RFD: a rotated frame, not supported
    path.write_bytes(spz_file(4, 1, 1, hand_streams(4), flags=0x2, extensions=rotated))
    with pytest.raises(SplatFileError, match="coordinate system 14"):
        spz.load(path)


def test_spz_degree_four_drops_to_three(tmp_path: Path) -> None:
    streams = hand_streams(3)[:5] + [bytes(range(100, 172))]  # 24 coefficients x RGB
    path = tmp_path / "deg4.spz"
    path.write_bytes(spz_file(3, 1, 4, streams))
    g = spz.load(path)
    assert g.degree == 3
    codes = np.arange(100, 145).reshape(15, 3)
    signs = spz._sh_signs(np.array([1.0, -1.0, -1.0]))
    np.testing.assert_allclose(g.sh[0, 1:], (codes - 128) / 128 * signs[:, None], atol=1e-7)


# ------------------------------------------------------------------------------------------
# Real files


def test_chair_splat_loads(shared_data: Path) -> None:
    path = shared_data / "splats" / "chair.splat"
    start = time.perf_counter()
    g = splat_io.load(path)
    print(f"chair.splat: {len(g)} splats in {1e3 * (time.perf_counter() - start):.0f} ms")
    assert len(g) == CHAIR_COUNT and g.degree == 0
    assert g.non_finite() is None
    norms = np.linalg.norm(g.quats, axis=1)
    assert np.all(np.abs(norms - 1) <= 1 / 64)  # stored unnormalised, as the viewer decodes them
    opacity = sigmoid(g.opacity_logits)
    assert np.all((opacity > 0) & (opacity < 1))
    colour = 0.5 + SH_C0 * g.sh[:, 0]
    assert np.all((colour >= -1e-6) & (colour <= 1 + 1e-6))
    assert np.all(np.abs(g.means) < 1.0)  # the NeRF-synthetic chair sits in the unit cube

    # An independent decode of the first records with struct.
    raw = path.read_bytes()
    for i in range(0, 2000, 97):
        values = struct.unpack_from("<6f8B", raw, 32 * i)
        np.testing.assert_array_equal(g.means[i], np.float32(values[:3]))
        np.testing.assert_allclose(np.exp(g.log_scales[i]), values[3:6], rtol=1e-6)
        np.testing.assert_allclose(colour[i], np.array(values[6:9]) / 255, atol=1e-6)
        np.testing.assert_allclose(g.quats[i], (np.array(values[10:14]) - 128) / 128)
        assert opacity[i] == pytest.approx(min(max(values[9] / 255, 0.25 / 255), 1 - 0.25 / 255))


def test_biker_spz_loads(shared_data: Path) -> None:
    path = shared_data / "splats" / "biker.spz"
    start = time.perf_counter()
    g = splat_io.load(path)
    print(f"biker.spz: {len(g)} splats in {1e3 * (time.perf_counter() - start):.0f} ms")
    packed = spz.read_packed(path)
    assert (packed.version, packed.sh_degree, packed.fractional_bits) == (4, 0, 12)
    assert len(g) == BIKER_COUNT and g.degree == 0
    assert g.non_finite() is None
    assert np.all(np.abs(np.linalg.norm(g.quats, axis=1) - 1) < 1e-5)
    opacity = sigmoid(g.opacity_logits)
    assert np.all((opacity > 0) & (opacity < 1))
    assert np.all((g.log_scales >= -10) & (g.log_scales <= 6))
    # Frame: the capture stands on a ground plane at y = 0 and rises along +y in the file (RUB,
    # y up); loaded into the .ply's RDF frame (y down) it rises along -y.
    assert g.means[:, 1].max() <= 0 and g.means[:, 1].min() < -3


def test_chair_resave_is_stable(shared_data: Path, tmp_path: Path) -> None:
    source = shared_data / "splats" / "chair.splat"
    first, second = tmp_path / "first.splat", tmp_path / "second.splat"
    splat.save(splat.load(source), first)
    splat.save(splat.load(first), second)
    assert first.read_bytes() == second.read_bytes()
    # The first save keeps every byte but the scales no float32 log reproduces (where logs are
    # coarser than scales: 39 % of the chair's), which move by at most 2e-7 relative.
    a = np.frombuffer(source.read_bytes(), splat.RECORD)
    b = np.frombuffer(first.read_bytes(), splat.RECORD)
    for field in ("position", "rgba", "rot"):
        np.testing.assert_array_equal(a[field], b[field])
    np.testing.assert_allclose(b["scale"], a["scale"], rtol=2.5e-7)


def test_biker_resave_is_bit_exact(shared_data: Path, tmp_path: Path) -> None:
    source = shared_data / "splats" / "biker.spz"
    first, second = tmp_path / "first.spz", tmp_path / "second.spz"
    spz.save(spz.load(source), first)
    spz.save(spz.load(first), second)
    assert first.read_bytes() == second.read_bytes()
    original, resaved = spz.read_packed(source), spz.read_packed(first)
    for name, array in original.arrays().items():  # Niantic's codes are already canonical
        np.testing.assert_array_equal(resaved.arrays()[name], array, err_msg=name)


# ------------------------------------------------------------------------------------------
# Round trips within the documented quantisation


def test_splat_round_trip_bounds(rng: np.random.Generator, tmp_path: Path) -> None:
    g = random_gaussians(rng, 4000, degree=2)
    path = tmp_path / "r.splat"
    splat_io.save(g, path)
    h = splat_io.load(path)
    assert len(h) == len(g) and h.degree == 0  # higher bands dropped
    np.testing.assert_array_equal(h.means, g.means)
    np.testing.assert_allclose(h.log_scales, g.log_scales, atol=1e-6)
    colour_in, colour_out = 0.5 + SH_C0 * g.sh[:, 0].astype(np.float64), 0.5 + SH_C0 * h.sh[:, 0]
    assert np.abs(colour_out - np.clip(colour_in, 0, 1)).max() <= 0.5 / 255 + 1e-6
    assert np.abs(sigmoid(h.opacity_logits) - sigmoid(g.opacity_logits)).max() <= 0.5 / 255 + 1e-6
    assert np.abs(h.quats - unit(g.quats)).max() <= 1 / 128 + 1e-6
    again = tmp_path / "again.splat"
    splat_io.save(h, again)
    assert again.read_bytes() == path.read_bytes()  # what was loaded saves to the same bytes


def test_splat_edge_values(tmp_path: Path) -> None:
    g = Gaussians(np.zeros((4, 3)), np.full((4, 3), -3.0), [[0, 0, 0, 0], [1, 0, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 2]],
                  [-40.0, 40.0, 0.0, 0.0], np.zeros((4, 1, 3)))
    path = tmp_path / "edge.splat"
    splat.save(g, path)
    rec = np.frombuffer(path.read_bytes(), splat.RECORD)
    np.testing.assert_array_equal(rec["rot"], [[255, 128, 128, 128], [255, 128, 128, 128],
                                               [0, 128, 128, 128], [128, 128, 128, 255]])
    np.testing.assert_array_equal(rec["rgba"][:, 3], [0, 255, 128, 128])
    h = splat.load(path)
    assert np.isfinite(h.opacity_logits).all()
    splat.save(Gaussians.empty(), path)
    assert path.read_bytes() == b"" and len(splat.load(path)) == 0


@pytest.mark.parametrize("version", [2, 3, 4])
def test_spz_round_trip_bounds(rng: np.random.Generator, tmp_path: Path, version: int) -> None:
    g = random_gaussians(rng, 4000, degree=3)
    path = tmp_path / "r.spz"
    spz.save(g, path, version)
    h = spz.load(path)
    bits = spz.read_packed(path).fractional_bits
    assert bits == 12 and len(h) == len(g) and h.degree == 3
    assert np.abs(h.means - g.means).max() <= 2.0 ** -(bits + 1)
    assert np.abs(h.log_scales - g.log_scales).max() <= 1 / 32 + 1e-6
    assert np.abs(h.sh[:, 0] - g.sh[:, 0]).max() <= 0.5 / (0.15 * 255) + 1e-6
    assert np.abs(sigmoid(h.opacity_logits) - sigmoid(g.opacity_logits)).max() <= 0.5 / 255 + 1e-6
    assert np.abs(h.sh[:, 1:4] - g.sh[:, 1:4]).max() <= 1 / 32 + 1e-6
    assert np.abs(h.sh[:, 4:] - g.sh[:, 4:]).max() <= 1 / 16 + 1e-6
    q = unit(g.quats)
    if version >= 3:
        error = np.abs(aligned(h.quats.astype(np.float64), q) - q)
        assert np.sort(error, axis=1)[:, :3].max() <= math.sqrt(0.5) / 511 / 2 + 1e-6
        assert error.max() <= 2.1e-3
    else:  # x, y, z of the w >= 0 quaternion within 1/255 (w is derived)
        q = np.where(q[:, :1] < 0, -q, q)
        assert np.abs(h.quats[:, 1:] - q[:, 1:]).max() <= 1 / 255 + 1e-6


@pytest.mark.parametrize("version", [2, 3, 4])
def test_spz_resave_is_bit_exact(rng: np.random.Generator, tmp_path: Path, version: int) -> None:
    g = random_gaussians(rng, 3000, degree=2)
    first, second, third = (tmp_path / f"{name}.spz" for name in ("a", "b", "c"))
    spz.save(g, first, version)
    spz.save(spz.load(first), second, version)
    spz.save(spz.load(second), third, version)
    if version >= 3:
        assert first.read_bytes() == second.read_bytes()
    assert second.read_bytes() == third.read_bytes()


def test_spz_smallest_three_near_ties_are_stable(rng: np.random.Generator) -> None:
    """Quaternions whose two largest components nearly tie: after quantising, the derived one can
    come out the smaller; the writer must still re-encode a decoded code to itself."""
    n = 20000
    a = rng.uniform(0.5, 0.7, n)
    q = np.stack([rng.uniform(-0.2, 0.2, n), a + rng.uniform(-2e-3, 2e-3, n), rng.uniform(-0.2, 0.2, n), a], 1)
    q = unit(q * rng.choice([-1.0, 1.0], (n, 4)))
    codes = spz._pack_rotations(q, 3)
    decoded = spz._decode_smallest_three(codes).astype(np.float32).astype(np.float64)
    np.testing.assert_array_equal(spz._pack_rotations(decoded, 3), codes)
    assert np.abs(aligned(decoded, q) - q).max() <= 2.1e-3


def test_spz_options_and_header_fields(rng: np.random.Generator, tmp_path: Path) -> None:
    g = random_gaussians(rng, 500, degree=3)
    path = tmp_path / "full.spz"
    spz.save(g, path, antialiased=True, sh1_bits=8, sh_rest_bits=8)
    assert spz.read_packed(path).antialiased
    assert np.abs(spz.load(path).sh[:, 1:] - g.sh[:, 1:]).max() <= 1 / 256 + 1e-6
    with pytest.raises(SplatFileError, match="SH bits"):
        spz.save(g, path, sh1_bits=9)
    with pytest.raises(SplatFileError, match="version 5"):
        spz.save(g, path, version=5)


def test_spz_fractional_bits_follow_the_extent(rng: np.random.Generator, tmp_path: Path) -> None:
    g = random_gaussians(rng, 500, degree=0, extent=5000.0)
    g.means[0] = [5000.0, -5000.0, 0.0]
    path = tmp_path / "big.spz"
    spz.save(g, path)
    bits = spz.read_packed(path).fractional_bits
    assert bits == 10  # 5000 * 2^11 overflows 24 bits
    assert np.abs(spz.load(path).means - g.means).max() <= 2.0 ** -(bits + 1)
    g.means[0, 0] = 9e6
    with pytest.raises(SplatFileError, match="24-bit"):
        spz.save(g, path)


def test_dispatch_knows_the_formats() -> None:
    assert {".ply", ".splat", ".spz"} <= set(splat_io.SUFFIXES)


# ------------------------------------------------------------------------------------------
# Bad files


def test_splat_bad_files(tmp_path: Path, shared_data: Path) -> None:
    path = tmp_path / "bad.splat"
    raw = (shared_data / "splats" / "chair.splat").read_bytes()[:32 * 10]
    path.write_bytes(raw[:-5])
    with pytest.raises(SplatFileError, match="multiple of the 32-byte") as error:
        splat.load(path)
    assert str(path) in first_line(error)
    rec = np.frombuffer(raw, splat.RECORD).copy()
    rec["position"][3, 1] = np.nan
    path.write_bytes(rec.tobytes())
    with pytest.raises(SplatFileError, match="non-finite position in splat 3"):
        splat.load(path)
    rec = np.frombuffer(raw, splat.RECORD).copy()
    rec["scale"][7, 2] = -1.0
    path.write_bytes(rec.tobytes())
    with pytest.raises(SplatFileError, match="negative scale in splat 7"):
        splat.load(path)


def test_spz_bad_headers(tmp_path: Path) -> None:
    path = tmp_path / "bad.spz"
    cases = {
        "not an SPZ file": b"PK\x03\x04" + bytes(40),
        "wrong magic": gzip.compress(b"XXXX" + bytes(60)),
        "unsupported SPZ version 7": gzip.compress(struct.pack("<4sIIBBBB", b"NGSP", 7, 1, 0, 12, 0, 0)
                                                   + bytes(64)),
        "unsupported SPZ version 5": spz_file(5, 1, 1, hand_streams(4)),
        "unsupported SH degree 5": spz_file(3, 1, 5, hand_streams(3)),
        "truncated: 20 of the 32": spz_file(4, 1, 1, hand_streams(4))[:20],
        "truncated: 7 of the 16": gzip.compress(b"NGSP\x03\x00\x00"),
    }
    for problem, data in cases.items():
        path.write_bytes(data)
        with pytest.raises(SplatFileError, match=problem) as error:
            spz.load(path)
        assert str(path) in first_line(error)


def test_spz_truncated_and_corrupt_data(tmp_path: Path) -> None:
    path = tmp_path / "bad.spz"
    whole3 = spz_file(3, 1, 1, hand_streams(3))
    whole4 = spz_file(4, 1, 1, hand_streams(4))
    cases = {
        "truncated": whole4[:-3],  # streams cut short
        "unexpected trailing data": whole4 + b"\0\0",
        "gzip stream is truncated": whole3[:-4],  # CRC/size trailer cut
        "corrupt gzip stream": whole3[:12] + bytes(b ^ 0x5A for b in whole3[12:]),
        "truncated: the header claims 1 points .45 bytes with the header., the gzip stream holds 16":
            spz_file(3, 1, 1, [], num_points=1),
        "holds 2 bytes": spz_file(4, 1, 0, [b"\0" * 9, b"\0\0"] + hand_streams(4)[2:5]),
        "5 streams in the table of contents": spz_file(4, 1, 1, hand_streams(4)[:5]),
    }
    for problem, data in cases.items():
        path.write_bytes(data)
        with pytest.raises(SplatFileError, match=problem):
            spz.load(path)
    damaged = bytearray(whole4)
    damaged[32 + 16 * 6] ^= 0xFF  # the first zstd frame's magic
    path.write_bytes(bytes(damaged))
    with pytest.raises(SplatFileError, match="corrupt zstd stream for positions"):
        spz.load(path)


def test_spz_headers_claiming_billions(tmp_path: Path) -> None:
    """Counts the data cannot hold fail before anything of their size is allocated."""
    path = tmp_path / "huge.spz"
    start = time.perf_counter()
    for version in (3, 4):
        path.write_bytes(spz_file(version, 1, 3, hand_streams(version), num_points=4_000_000_000))
        with pytest.raises(SplatFileError, match="claims 4000000000 points"):
            spz.load(path)
    # A claim the ratio check lets through is refused from the gzip trailer, before decompressing.
    path.write_bytes(spz_file(3, 1, 1, hand_streams(3), num_points=1000))
    with pytest.raises(SplatFileError, match="truncated: the header claims 1000 points .29016 bytes"):
        spz.load(path)
    header = struct.pack("<4sIIBBBBI12s", b"NGSP", 4, 10_000, 0, 12, 0, 5, 32, bytes(12))
    toc = b"".join(struct.pack("<QQ", 10, s) for s in (90_000, 10_000, 30_000, 30_000, 40_000))
    path.write_bytes(header + toc + bytes(50))
    with pytest.raises(SplatFileError, match="corrupt zstd|decompresses"):
        spz.load(path)
    assert time.perf_counter() - start < 2.0


def test_writers_refuse_non_finite(rng: np.random.Generator, tmp_path: Path) -> None:
    for name in ("means", "log_scales", "quats", "opacity_logits", "sh"):
        g = random_gaussians(rng, 20, degree=1)
        getattr(g, name).reshape(-1)[5] = np.nan
        for path in (tmp_path / "x.splat", tmp_path / "x.spz"):
            with pytest.raises(SplatFileError, match=f"Gaussians.{name} holds NaN") as error:
                splat_io.save(g, path)
            assert str(path) in first_line(error)
            assert not path.exists()
    with pytest.raises(SplatFileError, match="zero Gaussians"):
        spz.save(Gaussians.empty(), tmp_path / "empty.spz")
    g = random_gaussians(rng, 5, degree=0)
    g.log_scales[2, 0] = 100.0  # exp overflows float32
    with pytest.raises(SplatFileError, match="overflows"):
        splat.save(g, tmp_path / "x.splat")


def test_spz_v4_without_zstandard(monkeypatch: pytest.MonkeyPatch, rng: np.random.Generator,
                                  tmp_path: Path, shared_data: Path) -> None:
    """zstandard is optional: v4 then fails with a clear message and v3 still works."""
    monkeypatch.setitem(sys.modules, "zstandard", None)  # makes `import zstandard` fail
    with pytest.raises(SplatFileError, match="'zstandard' package"):
        spz.load(shared_data / "splats" / "biker.spz")
    g = random_gaussians(rng, 10, degree=1)
    with pytest.raises(SplatFileError, match="'zstandard' package"):
        spz.save(g, tmp_path / "x.spz")
    spz.save(g, tmp_path / "x.spz", version=3)
    assert len(spz.load(tmp_path / "x.spz")) == 10


def _zero_zstd_frame(size: int) -> bytes:
    """A zstd frame of `size` zero bytes, compressed in pieces (never `size` bytes in memory)."""
    import zstandard
    out = zstandard.ZstdCompressor(level=3).compressobj()
    piece = bytes(1 << 22)
    frames = [out.compress(piece[:min(len(piece), size - done)]) for done in range(0, size, len(piece))]
    return b"".join(frames) + out.flush()


def test_spz_decompression_bomb_fails_before_allocating(tmp_path: Path) -> None:
    """The issue's reproducer: a small v4 file whose zstd streams really hold 12 million points
    (zeros compress by thousands) passes the compression-ratio bound; the Gaussian ceiling
    (formats_common.limits) refuses it from the header, in bounded time and memory."""
    import tracemalloc

    n = 12_000_000
    sizes = spz._stream_sizes(n, 4, 0)
    frames = [(_zero_zstd_frame(s), s) for s in sizes if s]
    padding = struct.pack("<II", 0x12345678, 110_000) + bytes(110_000)  # an unknown extension
    header = struct.pack("<4sIIBBBBI12s", b"NGSP", 4, n, 0, 12, spz.FLAG_EXTENSIONS, len(frames),
                         32 + len(padding), bytes(12))
    toc = b"".join(struct.pack("<QQ", len(f), s) for f, s in frames)
    path = tmp_path / "bomb.spz"
    path.write_bytes(header + padding + toc + b"".join(f for f, _ in frames))
    assert path.stat().st_size < 200_000
    tracemalloc.start()
    start = time.perf_counter()
    try:
        with pytest.raises(SplatFileError, match="declares 12000000 points, more than the limit"):
            spz.load(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert time.perf_counter() - start < 1.0 and peak < 16 * path.stat().st_size


def test_every_reader_checks_the_gaussian_ceiling(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The ceiling is the user's to raise; each reader refuses a file above it, naming it."""
    from addon.core.formats_common import limits

    rng = np.random.default_rng(4)
    g = random_gaussians(rng, 40, 1)
    for suffix in (".ply", ".splat", ".spz"):
        splat_io.save(g, tmp_path / f"g{suffix}")
    monkeypatch.setattr(limits, "MAX_GAUSSIANS", 39)
    for suffix in (".ply", ".splat", ".spz"):
        with pytest.raises(SplatFileError, match=r"g\.\w+: declares 40 .*limit of 39"):
            splat_io.load(tmp_path / f"g{suffix}")
    monkeypatch.setattr(limits, "MAX_GAUSSIANS", 40)
    for suffix in (".ply", ".splat", ".spz"):
        assert len(splat_io.load(tmp_path / f"g{suffix}")) == 40
