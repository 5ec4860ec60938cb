"""Rendered images on disk: PNG stores straight alpha, EXR keeps premultiplied floats."""

from __future__ import annotations

import numpy as np
import OpenImageIO as oiio

from addon.core.image_io import write_image


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
