"""The .spz gzip bomb (issue 29): a 380 KB file of 6 million degree-3 points (zeros, which
deflate a thousand to one) died with a raw MemoryError under a 4 GiB address space. Now the
load holds the decompressed data once and decodes SH in place; a header claiming more than the
gzip trailer says the stream holds is refused before decompressing; and a genuine allocation
failure is a SplatFileError saying how much memory the file needs."""

from __future__ import annotations

import os
import struct
import sys
import time
import tracemalloc
import zlib
from pathlib import Path

import pytest

from addon.core.formats import registry, spz
from addon.core.formats_common.errors import SplatFileError
from limited import load_limited
from scripts import fuzz_hostile

MAGIC = 0x5053474E


def gzip_bomb(path: Path, n: int, degree: int, zeros: int | None = None, noise: int = 0) -> Path:
    """A v3 file declaring `n` points whose stream holds `noise` random bytes then `zeros` zero
    bytes (all it needs by default), compressed in pieces (never all in memory)."""
    total = sum(spz._stream_sizes(n, 3, degree))
    zeros = total if zeros is None else zeros
    out = zlib.compressobj(9, zlib.DEFLATED, 16 + 15)
    parts = [out.compress(struct.pack("<IIIBBBB", MAGIC, 3, n, degree, 12, 0, 0) + os.urandom(noise))]
    piece = bytes(1 << 22)
    for done in range(0, zeros, len(piece)):
        parts.append(out.compress(piece[:min(len(piece), zeros - done)]))
    path.write_bytes(b"".join(parts) + out.flush())
    return path


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="address-space limit")
def test_the_6m_point_gzip_bomb_loads_or_is_refused_under_4_gib(tmp_path: Path, monkeypatch) -> None:
    """With the expansion bound raised past it (formats_common.limits), the bomb still loads or fails
    by name (the bound itself refuses it at once: test_spz_expansion...)."""
    path = gzip_bomb(tmp_path / "bomb.spz", 6_000_000, 3)
    assert path.stat().st_size < 400_000
    monkeypatch.setenv("SPLAT_MAX_EXPANSION", "1000000")
    kind, text = load_limited(path, memory_gib=4.0, seconds=120)
    assert kind == "loaded" and text == "6000000" or \
        kind == "SplatFileError" and "needs about" in text and text.startswith(str(path)), (kind, text)


def test_running_out_of_memory_says_how_much_the_file_needs(tmp_path: Path, monkeypatch) -> None:
    path = tmp_path / "small.spz"
    gzip_bomb(path, 1000, 3)

    def no_memory(*args, **kwargs):
        raise MemoryError
    monkeypatch.setattr(spz, "unpack", no_memory)
    for read in (spz.load, lambda p: registry.read(p)[0]):
        with pytest.raises(SplatFileError, match=r"small.spz: not enough memory: loading 1000 points of "
                                                 r"SH degree 3 needs about 0\.0 GiB"):
            read(path)
    assert 2.5 * 2**30 < spz.memory_needed(6_000_000, 3) < 3.5 * 2**30  # measured: 2.5 GB resident


def test_a_header_claiming_more_than_the_gzip_trailer_is_refused_before_decompressing(tmp_path: Path) -> None:
    """3M points need 195 MB; the stream holds 100 KB of noise and 150 MB of zeros (the ratio
    bound lets it through). Decompressing first held 150 MB (twice) before finding it short."""
    path = gzip_bomb(tmp_path / "short.spz", 3_000_000, 3, zeros=150 << 20, noise=100_000)
    tracemalloc.start()
    start = time.process_time()
    try:
        with pytest.raises(SplatFileError, match="truncated: the header claims 3000000 points"):
            spz.load(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 16 * path.stat().st_size and time.process_time() - start < 0.5


@pytest.mark.parametrize("version", [2, 3])
def test_a_gzip_stream_declaring_10m_points_is_refused_by_its_expansion(tmp_path: Path, version: int) -> None:
    """Issue 33: a 185 KB gzip .spz (v2) declaring 10M points loaded 10M Gaussians (1.95 GB):
    deflate's 1032:1 and the count cap both let it through. Refused once the 16 header bytes are
    inflated, naming the file, the declared size and the bound, in bounded time and memory."""
    path = tmp_path / "bomb.spz"
    path.write_bytes(fuzz_hostile.spz_gzip_bomb(10_000_000, version)["a.spz"])
    assert path.stat().st_size < 200_000
    tracemalloc.start()
    start = time.process_time()
    try:
        with pytest.raises(SplatFileError, match=r"bomb.spz: declares 10000000 Gaussians of SH degree 0 "
                                                 r"\(534\.1 MiB loaded\) in \d+ bytes: \d+ bytes decoded per "
                                                 r"byte read, more than the bound of 256 .*SPLAT_MAX_EXPANSION"):
            spz.load(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 4 * path.stat().st_size and time.process_time() - start < 0.5


def test_a_zstd_file_declaring_millions_of_points_is_refused_by_its_expansion(tmp_path: Path) -> None:
    """v4: 2M points in 40 KB of zstd frames (zeros after 40 KB of noise: past Niantic's own
    1024:1 check); refused from the header, before any frame is decompressed."""
    zstandard = pytest.importorskip("zstandard")
    n = 2_000_000
    sizes = [size for size in spz._stream_sizes(n, 4, 0) if size]
    streams = [os.urandom(40_000) + bytes(size - 40_000) for size in sizes[:1]] + [bytes(s) for s in sizes[1:]]
    frames = [zstandard.ZstdCompressor(level=3).compress(stream) for stream in streams]
    header = spz._NGSP_HEADER.pack(MAGIC, 4, n, 0, 12, 0, len(frames), spz._NGSP_HEADER.size, bytes(12))
    toc = b"".join(struct.pack("<QQ", len(f), size) for f, size in zip(frames, sizes))
    path = tmp_path / "bomb.spz"
    path.write_bytes(header + toc + b"".join(frames))
    assert 20_000 < path.stat().st_size < 60_000
    with pytest.raises(SplatFileError, match=r"bomb.spz: declares 2000000 Gaussians of SH degree 0 .* more "
                                             r"than the bound of 256"):
        spz.load(path)
