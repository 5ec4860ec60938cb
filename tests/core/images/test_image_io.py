"""Images on disk: PNG stores straight alpha, EXR keeps premultiplied floats, Blender's
multilayer EXR channels round-trip, and every write is atomic."""

from __future__ import annotations

import numpy as np
import OpenImageIO as oiio
import pytest

from addon.core.images import exr_layers
from addon.core.images.files import ImageError, write_image, write_pixels


def _read(path, unassociated: bool) -> np.ndarray:
    config = oiio.ImageSpec()
    if unassociated:
        config.attribute("oiio:UnassociatedAlpha", 1)
    image = oiio.ImageInput.open(str(path), config)
    try:
        return image.read_image("float")
    finally:
        image.close()


def test_png_holds_straight_colour(tmp_path, rng) -> None:
    alpha = rng.uniform(0.2, 1.0, (6, 9)).astype(np.float32)
    straight = rng.uniform(0.0, 1.0, (6, 9, 3)).astype(np.float32)
    write_image(tmp_path / "a.png", straight * alpha[..., None], alpha)
    stored = _read(tmp_path / "a.png", unassociated=True)  # the bytes as they are in the file
    assert np.abs(stored[..., :3] - straight).max() <= 0.5 / 255 + 1e-6
    assert np.abs(stored[..., 3] - alpha).max() <= 0.5 / 255 + 1e-6


def test_exr_keeps_premultiplied_floats(tmp_path, rng) -> None:
    alpha = rng.uniform(0.0, 1.0, (5, 4)).astype(np.float32)
    rgb = rng.uniform(0.0, 2.0, (5, 4, 3)).astype(np.float32) * alpha[..., None]
    write_image(tmp_path / "a.exr", rgb, alpha)
    stored = _read(tmp_path / "a.exr", unassociated=False)
    assert np.array_equal(stored[..., :3], rgb) and np.array_equal(stored[..., 3], alpha)
    assert not list(tmp_path.glob(".*tmp*"))  # the temporary file was renamed


def test_exr_layers_round_trip_and_append(tmp_path, rng) -> None:
    path = tmp_path / "layers.exr"
    planes = {f"ViewLayer.Combined.{c}": rng.uniform(0, 1, (4, 6)).astype(np.float32)
              for c in "RGBA"}
    exr_layers.write_channels(path, planes)
    depth = rng.uniform(1, 9, (4, 6, 1)).astype(np.float32)
    exr_layers.append_layers(path, {"Splats.Depth": ("Z", depth)})
    channels = exr_layers.read_channels(path)
    for name, plane in planes.items():
        assert np.array_equal(channels[name], plane)
    assert np.array_equal(exr_layers.find_pass(channels, "Splats", "Depth", "Z"), depth)
    assert exr_layers.find_pass(channels, "Splats", "Combined", "RGBA") is None
    assert sorted(p.name for p in tmp_path.iterdir()) == ["layers.exr"]  # no temporary left


def test_failed_write_names_the_file_and_keeps_the_old_one(tmp_path) -> None:
    path = tmp_path / "keep.unknownformat"
    path.write_bytes(b"precious")
    with pytest.raises(ImageError, match="keep.unknownformat: cannot write image"):
        write_pixels(path, np.zeros((2, 2, 3), np.uint8))
    assert path.read_bytes() == b"precious"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.unknownformat"]
