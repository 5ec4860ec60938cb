"""The SuperSplat compressed .ply writer, held against the existing reader (`compressed_ply`):
round trips within the quantisation stated in `formats/compressed_ply_write.py`, the real
SuperSplat file re-saved with its own chunks, and the layout SuperSplat expects."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from addon.core import splat_io
from addon.core.formats import compressed_ply_write as writer
from addon.core.formats import ply
from addon.core.formats_common.errors import SplatFileError
from addon.core.formats_common.morton import morton_order
from addon.core.gaussians import Gaussians
from addon.core.render.renderer import render
from scenes import playbot_camera, psnr

SH_C0 = 0.28209479177387814
PACKED = ["packed_position", "packed_rotation", "packed_scale", "packed_color"]


def random_gaussians(rng: np.random.Generator, n: int, degree: int) -> Gaussians:
    k = (degree + 1) ** 2
    sh = rng.uniform(-3.9, 3.9, (n, k, 3))
    sh[:, 0] = rng.uniform(-1.7, 1.7, (n, 3))
    return Gaussians(rng.uniform(-5.0, 5.0, (n, 3)), rng.uniform(-9.0, 1.0, (n, 3)),
                     rng.normal(size=(n, 4)) * rng.uniform(0.1, 5.0, (n, 1)), rng.normal(0.0, 3.0, n), sh)


def tables(path: Path) -> tuple[np.ndarray, np.ndarray, ply.PlyHeader]:
    header = ply.read_header(path)
    read = ply.read_elements(path, header, ["chunk", "vertex"])
    return (read["chunk"].gather(writer.CHUNK_PROPERTIES, np.float64),
            read["vertex"].gather(PACKED, np.uint32), header)


def per_row(chunk_values: np.ndarray, n: int) -> np.ndarray:
    return np.repeat(chunk_values, writer.CHUNK_SIZE, axis=0)[:n]


def unit(q: np.ndarray) -> np.ndarray:
    q = q.astype(np.float64)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-x.astype(np.float64)))


@pytest.mark.parametrize("degree", [0, 1, 3])
def test_round_trip_within_the_stated_quantisation(rng: np.random.Generator, tmp_path: Path, degree: int) -> None:
    n = 1000  # not a multiple of 256: a partial last chunk
    original = random_gaussians(rng, n, degree)
    path = tmp_path / "x.compressed.ply"
    splat_io.save(original, path)
    back = splat_io.load(path)
    want = original.subset(morton_order(original.means))
    chunks, _, header = tables(path)
    assert [e.name for e in header.elements] == ["chunk", "vertex"] + (["sh"] if degree else [])
    assert len(chunks) == math.ceil(n / 256) and back.degree == degree

    lo, hi = per_row(chunks[:, 0:3], n), per_row(chunks[:, 3:6], n)
    steps = (hi - lo) / np.array([2047.0, 1023.0, 2047.0])
    assert np.all(np.abs(back.means - want.means) <= steps / 2 + 1e-6)
    lo, hi = per_row(chunks[:, 6:9], n), per_row(chunks[:, 9:12], n)
    steps = (hi - lo) / np.array([2047.0, 1023.0, 2047.0])
    assert np.all(np.abs(back.log_scales - want.log_scales) <= steps / 2 + 1e-5)
    lo, hi = per_row(chunks[:, 12:15], n), per_row(chunks[:, 15:18], n)
    colour = 0.5 + SH_C0 * want.sh[:, 0].astype(np.float64)
    assert np.all(np.abs(0.5 + SH_C0 * back.sh[:, 0] - colour) <= (hi - lo) / 510 + 1e-6)
    opacity_error = np.abs(sigmoid(back.opacity_logits) - sigmoid(want.opacity_logits))
    assert np.all(opacity_error <= 0.5 / 255 + 1e-7)
    assert np.all(np.abs(np.sum(unit(back.quats) * unit(want.quats), axis=1)) >= 1 - 1e-5)
    if degree:
        assert np.all(np.abs(back.sh[:, 1:] - want.sh[:, 1:]) <= 1 / 32 + 1e-6)
        inner = np.abs(want.sh[:, 1:]) < 4 - 1 / 32
        assert np.all(np.abs(back.sh[:, 1:] - want.sh[:, 1:])[inner] <= 1 / 64 + 1e-6)


def test_out_of_range_values_clamp(tmp_path: Path) -> None:
    g = Gaussians(np.zeros((2, 3)), [[30.0, -30.0, 0.0], [0.0, 0.0, 0.0]], [[1, 0, 0, 0], [0, 0, 0, 0]],
                  [50.0, -50.0], np.full((2, 4, 3), 9.0))
    writer.save(g, tmp_path / "x.ply", keep_order=True)
    back = ply.load(tmp_path / "x.ply")
    np.testing.assert_allclose(back.log_scales[0, :2], [20.0, -20.0])
    np.testing.assert_allclose(back.sh[:, 1:], 4.0)
    np.testing.assert_allclose(sigmoid(back.opacity_logits), [1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(np.abs(unit(back.quats)[:, 0]), 1.0, atol=1e-6)  # zero quat: identity


def test_playbot_round_trip_render(shared_data: Path, tmp_path: Path) -> None:
    g = ply.load(shared_data / "splats" / "playbot_125k_sh2.ply")
    writer.save(g, tmp_path / "playbot.compressed.ply")
    back = ply.load(tmp_path / "playbot.compressed.ply")
    camera = playbot_camera()
    # measured 51.6 dB at 320x240; 5.0 MB against the PLY's 20.5 MB
    assert psnr(render(back, camera).rgb, render(g, camera).rgb) >= 48.0
    assert (tmp_path / "playbot.compressed.ply").stat().st_size < 5_100_000


def test_supersplat_file_re_saves_with_its_own_chunks(shared_data: Path, tmp_path: Path) -> None:
    source = shared_data / "splats" / "guitar.compressed.ply"
    writer.save(ply.load(source), tmp_path / "guitar.compressed.ply", keep_order=True)
    chunks, packed, header = tables(source)
    chunks2, packed2, header2 = tables(tmp_path / "guitar.compressed.ply")
    assert [(e.name, e.count, e.names) for e in header.elements] == \
        [(e.name, e.count, e.names) for e in header2.elements]
    np.testing.assert_array_equal(chunks2, chunks)
    for column in (0, 2, 3):  # position, scale, colour words: identical
        np.testing.assert_array_equal(packed2[:, column], packed[:, column], err_msg=PACKED[column])
    # Rotation: re-encoding a decoded quaternion can pick another "largest" component on a near
    # tie (the derived one is not exact); all still decode to the same rotation.
    assert np.mean(packed2[:, 1] == packed[:, 1]) > 0.99
    a, b = ply.load(source), ply.load(tmp_path / "guitar.compressed.ply")
    assert np.all(np.abs(np.sum(unit(a.quats) * unit(b.quats), axis=1)) >= 1 - 1e-5)


def test_refuses_non_finite_and_writes_empty(tmp_path: Path) -> None:
    g = Gaussians(np.zeros((3, 3)), np.zeros((3, 3)), np.ones((3, 4)), np.zeros(3), np.zeros((3, 1, 3)))
    g.sh[1, 0, 2] = np.nan
    with pytest.raises(SplatFileError, match="non-finite") as error:
        writer.save(g, tmp_path / "x.compressed.ply")
    assert "x.compressed.ply" in str(error.value)
    assert not list(tmp_path.iterdir())
    writer.save(Gaussians.empty(), tmp_path / "empty.compressed.ply")
    assert b"element chunk 0" in (tmp_path / "empty.compressed.ply").read_bytes()
