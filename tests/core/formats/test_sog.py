"""PlayCanvas SOG (folder and .sog bundle) and the streamed SOG LOD set.

Real data: PlayCanvas' own LOD set of PLAYBOT, whose level 2 is the very data of
`playbot_125k_sh2.ply` (splat-transform decoded it): it must load bit for bit, and every level
must render like the PLY. Round trips are held to the bounds in `formats/sog.py`; malformed files
must give a SplatFileError naming the file.
"""

from __future__ import annotations

import json
import math
import shutil
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from addon.core import splat_io
from addon.core.formats import ply, sog, sog_lod
from addon.core.formats_common import codebook, webp
from addon.core.formats_common.errors import SplatFileError
from addon.core.formats_common.morton import morton_order
from addon.core.gaussians import Gaussians
from addon.core.render.renderer import render
from scenes import playbot_camera, psnr

LOD_COUNTS = [500_000, 250_000, 125_000, 31_000, 8_406, 3_000, 1_873]
# Render PSNR of each LOD level against the PLY (= level 2) at 160x120 with `playbot_camera`:
# the levels are different decimations of one capture, so coarser levels differ more.
LOD_MIN_PSNR = [28.5, 30.0, math.inf, 25.0, 23.5, 21.5, 21.3]  # measured 29.4, 31.0, inf, 26.2, 24.6, 22.5, 22.4


def random_gaussians(rng: np.random.Generator, n: int, degree: int) -> Gaussians:
    k = (degree + 1) ** 2
    sh = rng.normal(0.0, 0.3, (n, k, 3))
    sh[:, 0] = rng.uniform(-1.7, 1.7, (n, 3))
    return Gaussians(rng.uniform(-3.0, 3.0, (n, 3)), rng.uniform(-7.0, 0.0, (n, 3)),
                     rng.normal(size=(n, 4)), rng.normal(0.0, 3.0, n), sh)


def unit(q: np.ndarray) -> np.ndarray:
    q = q.astype(np.float64)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


@pytest.fixture()
def playbot_ply(shared_data: Path) -> Gaussians:
    return ply.load(shared_data / "splats" / "playbot_125k_sh2.ply")


# ------------------------------------------------------------------------------------------
# Real data


def test_lod_level_2_is_the_ply_bit_for_bit(shared_data: Path, playbot_ply: Gaussians) -> None:
    g = sog_lod.load(shared_data / "splats" / "playbot_sog" / "lod-meta.json", level=2)
    for name, want in playbot_ply.arrays().items():
        np.testing.assert_array_equal(getattr(g, name), want, err_msg=name)


def test_every_lod_level_loads_and_renders_like_the_ply(shared_data: Path, playbot_ply: Gaussians) -> None:
    lod = shared_data / "splats" / "playbot_sog" / "lod-meta.json"
    assert sog_lod.levels(lod) == 7
    camera = playbot_camera()
    reference = render(playbot_ply, camera).rgb
    for level, (count, floor) in enumerate(zip(LOD_COUNTS, LOD_MIN_PSNR)):
        g = sog_lod.load(lod, level)
        assert len(g) == count and g.degree == 2
        assert g.non_finite() is None
        assert psnr(render(g, camera).rgb, reference) >= floor, level
    assert len(splat_io.load(lod)) == LOD_COUNTS[0]  # the table reads the finest level
    assert len(splat_io.load(lod.parent)) == LOD_COUNTS[0]  # and the folder holding it


def test_a_single_chunk_folder_loads_as_sog(shared_data: Path) -> None:
    folder = shared_data / "splats" / "playbot_sog" / "3_0"
    g = splat_io.load(folder / "meta.json")
    assert len(g) == 31_000
    assert len(sog.load(folder)) == 31_000
    info = sog.read_info(folder)
    assert (info.count, info.sh_degree, info.palette_size) == (31_000, 2, 16384)


def test_playbot_round_trip_renders_within_psnr(tmp_path: Path, playbot_ply: Gaussians) -> None:
    sog.save(playbot_ply, tmp_path / "playbot.sog")
    g = sog.load(tmp_path / "playbot.sog")
    camera = playbot_camera()
    # Measured 48.4 dB at 320x240 (SH palette of 65536 from 125k Gaussians; 2.8 MB against the
    # PLY's 20.5 MB).
    assert psnr(render(g, camera).rgb, render(playbot_ply, camera).rgb) >= 45.0
    assert (tmp_path / "playbot.sog").stat().st_size < 3_200_000


# ------------------------------------------------------------------------------------------
# Round trips


def test_webp_bytes_round_trip_exactly(rng: np.random.Generator, tmp_path: Path) -> None:
    pixels = rng.integers(0, 256, (37, 53, 4), dtype=np.uint8)
    pixels[..., 3] = rng.integers(1, 256, (37, 53))  # RGB under alpha 0 is libwebp's to drop
    webp.write_rgba(tmp_path / "x.webp", pixels)
    assert webp.read_size(tmp_path / "x.webp") == (53, 37, 4)
    np.testing.assert_array_equal(webp.read_rgba(tmp_path / "x.webp"), pixels)


def test_round_trip_within_the_stated_quantisation(rng: np.random.Generator, tmp_path: Path) -> None:
    original = random_gaussians(rng, 3000, degree=3)
    sog.save(original, tmp_path / "meta.json")
    meta = json.loads((tmp_path / "meta.json").read_text())
    back = sog.load(tmp_path / "meta.json")
    want = original.subset(morton_order(original.means))  # the order the writer stores
    assert meta["count"] == len(back) == 3000 and back.degree == 3

    # Position: half a 16-bit step in the log domain (plus the float32 rounding of the result).
    n = np.sign(want.means) * np.log1p(np.abs(want.means.astype(np.float64)))
    n_back = np.sign(back.means) * np.log1p(np.abs(back.means.astype(np.float64)))
    step = (np.array(meta["means"]["maxs"]) - meta["means"]["mins"]) / 65535
    assert np.all(np.abs(n_back - n) <= step / 2 + 2e-7)
    # Rotation: the same rotation (q or -q), components within 2.8e-3 and the derived one within 4e-3.
    dots = np.abs(np.sum(unit(back.quats) * unit(want.quats), axis=1))
    assert np.all(dots >= math.cos(0.01))
    # Log scales and DC colours: exactly the nearest codebook entry. Not the colour of Gaussians
    # whose opacity byte is 0: libwebp drops RGB under alpha 0 (they are invisible).
    def opacity(logits): return 1 / (1 + np.exp(-logits.astype(np.float64)))
    seen = np.rint(opacity(want.opacity_logits) * 255) > 0
    assert seen.sum() > 2500
    for values, got, book in ((want.log_scales, back.log_scales, meta["scales"]["codebook"]),
                              (want.sh[seen, 0], back.sh[seen, 0], meta["sh0"]["codebook"])):
        book = np.asarray(book, np.float32)
        nearest = np.min(np.abs(values[..., None].astype(np.float64) - book), axis=-1)
        np.testing.assert_allclose(np.abs(got - values.astype(np.float64)), nearest, atol=1e-6)
    # Opacity: half an 8-bit step (byte 0 and 255 read as 1e-6 and 1 - 1e-6).
    assert np.all(np.abs(opacity(back.opacity_logits) - opacity(want.opacity_logits)) <= 0.5 / 255 + 1e-6)
    # SH rest: a palette entry, each value a codebook entry.
    book = np.asarray(meta["shN"]["codebook"], np.float32)
    assert np.isin(back.sh[:, 1:], book).all()
    assert meta["shN"]["count"] == sog.palette_size(3000) == 2048
    rms = np.sqrt(np.mean((back.sh[:, 1:] - want.sh[:, 1:]) ** 2))
    assert rms < 0.6 * np.sqrt(np.mean(want.sh[:, 1:] ** 2))  # noise data: the hardest case


def test_bundle_and_folder_hold_the_same_data(rng: np.random.Generator, tmp_path: Path) -> None:
    g = random_gaussians(rng, 500, degree=1)
    sog.save(g, tmp_path / "a.sog", antialiased=True)
    (tmp_path / "b").mkdir()
    sog.save(g, tmp_path / "b" / "meta.json", antialiased=True)
    a, b = sog.load(tmp_path / "a.sog"), sog.load(tmp_path / "b")
    for name, value in a.arrays().items():
        np.testing.assert_array_equal(value, getattr(b, name), err_msg=name)
    assert sog.read_info(tmp_path / "a.sog").antialiased
    with zipfile.ZipFile(tmp_path / "a.sog") as archive:
        assert sorted(archive.namelist()) == sorted(
            ["meta.json", "means_l.webp", "means_u.webp", "quats.webp", "scales.webp", "sh0.webp",
             "shN_centroids.webp", "shN_labels.webp"])
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporaries left


def test_re_saving_a_loaded_sog_keeps_the_render(shared_data: Path, tmp_path: Path) -> None:
    g = sog.load(shared_data / "splats" / "playbot_sog" / "4_0")
    splat_io.save(g, tmp_path / "again.sog")
    back = splat_io.load(tmp_path / "again.sog")
    camera = playbot_camera()
    assert psnr(render(back, camera).rgb, render(g, camera).rgb) >= 40.0


def test_degenerate_inputs(tmp_path: Path) -> None:
    for n in (0, 1, 5):
        g = Gaussians(np.full((n, 3), 2.0), np.full((n, 3), -3.0), np.tile([1.0, 0, 0, 0], (n, 1)),
                      np.zeros(n), np.zeros((n, 4, 3)))
        sog.save(g, tmp_path / f"{n}.sog")
        back = sog.load(tmp_path / f"{n}.sog")
        assert len(back) == n
        if n:
            np.testing.assert_allclose(back.means, 2.0, rtol=1e-6)
            np.testing.assert_allclose(back.log_scales, -3.0)


def test_codebook_is_optimal_for_few_values() -> None:
    values = np.array([1.0, 1.0, 2.0, 5.0, 5.0, 5.0])
    book, labels = codebook.scalar_codebook(values, 3)
    np.testing.assert_allclose(book, [1.0, 2.0, 5.0], rtol=1e-6)
    np.testing.assert_array_equal(book[labels], values)
    centroids, point_labels = codebook.palette(np.eye(5), 3, coarse=2)
    assert len(centroids) == 3 and point_labels.max() == 2


def test_writer_refuses_bad_input(tmp_path: Path) -> None:
    g = Gaussians(np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 4)), np.zeros(3), np.zeros((3, 1, 3)))
    g.means[1, 2] = np.inf
    with pytest.raises(SplatFileError, match="non-finite"):
        sog.save(g, tmp_path / "x.sog")
    with pytest.raises(SplatFileError, match="meta.json"):
        sog.save(Gaussians.empty(), tmp_path / "x.json")
    assert not list(tmp_path.iterdir())


# ------------------------------------------------------------------------------------------
# Malformed files


@pytest.fixture(scope="module")
def small_sog_original(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("small")
    sog.save(random_gaussians(np.random.default_rng(7), 300, degree=1), folder / "meta.json")
    webp.write_rgba(folder / "tiny.webp", np.full((4, 4, 4), 255, np.uint8))
    webp.write_rgba(folder / "big.webp", np.full((200, 200, 4), 255, np.uint8))
    return folder


@pytest.fixture()
def small_sog(small_sog_original: Path, tmp_path: Path) -> Path:
    """A fresh copy of a small SOG folder, for a test to damage."""
    return Path(shutil.copytree(small_sog_original, tmp_path / "small"))


def edit_meta(folder: Path, change) -> Path:
    meta = json.loads((folder / "meta.json").read_text())
    change(meta)
    (folder / "meta.json").write_text(json.dumps(meta))
    return folder / "meta.json"


@pytest.mark.parametrize("change, message", [
    (lambda m: m.pop("version"), "version 1"),
    (lambda m: m.update(version=3), "unsupported SOG version 3"),
    (lambda m: m.update(count=10 ** 12), "bad count"),
    (lambda m: m.update(count=1_000), "too small for 1000"),
    (lambda m: m.update(count=100_000), "declares 100000 Gaussians of SH degree 1 .* bytes decoded per byte read"),
    (lambda m: m.update(count=-1), "bad count"),
    (lambda m: m["means"].pop("mins"), "means.mins"),
    (lambda m: m["means"].update(maxs=[1, 2]), "means.maxs"),
    (lambda m: m["means"].update(maxs=[1e6, 1, 1]), "beyond float32"),
    (lambda m: m["scales"].update(codebook=[0.0] * 300), "at most 256"),
    (lambda m: m["scales"].update(codebook=[0.0]), "beyond its 1-entry codebook"),
    (lambda m: m["sh0"].update(codebook=["x"] * 256), "sh0.codebook"),
    (lambda m: m["shN"].update(codebook=[1e300] * 256), "beyond float32"),
    (lambda m: m["quats"].update(files=["../../etc/passwd"]), "relative path inside"),
    (lambda m: m["quats"].update(files=["missing.webp"]), "missing image 'missing.webp'"),
    (lambda m: m["quats"].update(files=["sh0.webp"]), "mode byte outside 252..255"),
    (lambda m: m["shN"].update(count=10), "beyond the 10-entry palette"),
    (lambda m: m["shN"].update(bands=2), "needs 512x"),
    (lambda m: m["shN"].update(count=70_000), "bad shN.count"),
    (lambda m: m["scales"].update(files=["tiny.webp"]), "is 4x4: too small for 300"),
    (lambda m: (m.update(count=3), m["scales"].update(files=["big.webp"])), "far larger than 3 Gaussians need"),
])
def test_bad_meta_is_a_clear_error(small_sog: Path, change, message: str) -> None:
    path = edit_meta(small_sog, change)
    with pytest.raises(SplatFileError, match=message) as error:
        sog.load(path)
    assert str(path) in str(error.value)


def test_bad_json_and_truncated_images(small_sog: Path) -> None:
    meta = small_sog / "meta.json"
    text = meta.read_text()
    meta.write_text(text[: len(text) // 2])
    with pytest.raises(SplatFileError, match="bad JSON"):
        sog.load(meta)
    meta.write_text("[1, 2]")
    with pytest.raises(SplatFileError, match="not a JSON object"):
        sog.load(meta)
    meta.write_text(text)
    image = small_sog / "quats.webp"
    image.write_bytes(image.read_bytes()[:40])
    with pytest.raises(SplatFileError, match="quats.webp"):
        sog.load(meta)
    image.write_bytes(b"")
    with pytest.raises(SplatFileError, match="quats.webp"):
        sog.load(meta)


def test_bad_bundles(small_sog: Path, tmp_path: Path) -> None:
    not_zip = tmp_path / "a.sog"
    not_zip.write_bytes(b"PK\x03\x04 not really")
    with pytest.raises(SplatFileError, match="not a .sog bundle"):
        sog.load(not_zip)
    with pytest.raises(SplatFileError, match="no such file"):
        sog.load(tmp_path / "missing.sog")
    no_meta = tmp_path / "b.sog"
    with zipfile.ZipFile(no_meta, "w") as archive:
        archive.write(small_sog / "quats.webp", "quats.webp")
    with pytest.raises(SplatFileError, match="missing 'meta.json'"):
        sog.load(no_meta)
    truncated = tmp_path / "c.sog"
    sog.save(sog.load(small_sog), truncated)
    truncated.write_bytes(truncated.read_bytes()[:-500])
    with pytest.raises(SplatFileError, match=str(truncated.name)):
        sog.load(truncated)


def test_deflated_bundle_reads(small_sog: Path, tmp_path: Path) -> None:
    bundle = tmp_path / "deflated.sog"
    with zipfile.ZipFile(bundle, "w", zipfile.ZIP_DEFLATED) as archive:
        for path in small_sog.iterdir():
            archive.write(path, path.name)
    a, b = sog.load(bundle), sog.load(small_sog)
    for name, value in a.arrays().items():
        np.testing.assert_array_equal(value, getattr(b, name), err_msg=name)


def test_missing_openimageio_is_named(small_sog: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "OpenImageIO", None)
    with pytest.raises(SplatFileError, match="'OpenImageIO'"):
        sog.load(small_sog)
    with pytest.raises(SplatFileError, match="'OpenImageIO'"):
        sog.save(Gaussians.empty(), tmp_path / "x.sog")
    assert not (tmp_path / "x.sog").exists()


@pytest.fixture()
def lod_copy(shared_data: Path, tmp_path: Path) -> Path:
    root = tmp_path / "lod"
    root.mkdir()
    for level in ("5_0", "6_0"):
        shutil.copytree(shared_data / "splats" / "playbot_sog" / level, root / level)
    index = json.loads((shared_data / "splats" / "playbot_sog" / "lod-meta.json").read_text())
    (root / "lod-meta.json").write_text(json.dumps(index))
    return root / "lod-meta.json"


def edit_index(path: Path, change) -> None:
    index = json.loads(path.read_text())
    change(index)
    path.write_text(json.dumps(index))


def test_lod_errors(lod_copy: Path) -> None:
    assert len(sog_lod.load(lod_copy, 6)) == LOD_COUNTS[6]
    with pytest.raises(SplatFileError, match="no LOD level 7"):
        sog_lod.load(lod_copy, 7)
    with pytest.raises(SplatFileError, match="missing chunk"):
        sog_lod.load(lod_copy, 0)  # its chunk folder was not copied
    edit_index(lod_copy, lambda i: i["tree"]["children"][0]["lods"]["6"].update(count=10 ** 6))
    with pytest.raises(SplatFileError, match="beyond chunk"):
        sog_lod.load(lod_copy, 6)
    edit_index(lod_copy, lambda i: i["tree"]["children"][0]["lods"]["6"].update(file=99, count=5))
    with pytest.raises(SplatFileError, match="bad run"):
        sog_lod.load(lod_copy, 6)
    edit_index(lod_copy, lambda i: i.update(filenames=["../../x/meta.json"]))
    with pytest.raises(SplatFileError, match="inside the set's folder"):
        sog_lod.load(lod_copy, 6)
    edit_index(lod_copy, lambda i: i.update(version=2))
    with pytest.raises(SplatFileError, match="unsupported streamed SOG version"):
        sog_lod.load(lod_copy, 6)
    lod_copy.write_text("{ not json")
    with pytest.raises(SplatFileError, match="bad JSON") as error:
        sog_lod.load(lod_copy)
    assert str(lod_copy) in str(error.value)


def test_corrupted_files_raise_only_splat_file_errors(small_sog_original: Path, rng: np.random.Generator,
                                                      tmp_path: Path) -> None:
    meta = (small_sog_original / "meta.json").read_bytes()
    images = {p.name: p.read_bytes() for p in small_sog_original.glob("*.webp")}
    sog.save(sog.load(small_sog_original), tmp_path / "a.sog")
    bundle = (tmp_path / "a.sog").read_bytes()
    folder = tmp_path / "fuzz"
    alphabet = list(b'0123456789 ,.-"[]{}:eE')
    for i in range(120):
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir()
        for name, data in images.items():
            (folder / name).write_bytes(data)
        data = bytearray(meta if i % 3 else bundle)
        if i % 4 == 0:
            data = data[:rng.integers(0, len(data))]
        for _ in range(rng.integers(1, 5) if data else 0):
            data[rng.integers(0, len(data))] = rng.choice(alphabet)
        if i % 3:
            (folder / "meta.json").write_bytes(bytes(data))
            victim = folder / sorted(images)[i % len(images)]
            image = bytearray(victim.read_bytes())
            image[rng.integers(0, len(image))] ^= 0xFF  # a damaged image too
            victim.write_bytes(bytes(image))
            target = folder
        else:
            target = tmp_path / "fuzz.sog"
            target.write_bytes(bytes(data))
        try:
            sog.load(target)
        except SplatFileError:
            pass
