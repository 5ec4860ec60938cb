"""A training step's photo to float (`files.rgb_float`, native/src/photo.c): bit for bit what
NumPy's `to_float(rgb_alpha(pixels)[0])` makes (astype(float32) times float32(1 / 255)), for
RGB and RGBA 8-bit pixels, on any thread count; other types and grey take NumPy's path."""

from __future__ import annotations

import numpy as np
import pytest

from addon.core import native
from addon.core.images import files


def _numpy(pixels: np.ndarray) -> np.ndarray:
    return files.to_float(files.rgb_alpha(pixels)[0])


@pytest.mark.parametrize("channels", [3, 4])
def test_eight_bit_photos_convert_bit_for_bit(rng, channels):
    pixels = rng.integers(0, 256, (301, 257, channels), dtype=np.uint8)
    pixels[0, :4, 0] = [0, 1, 254, 255]
    want = _numpy(pixels)
    for threads in (1, 2, 3, 0):
        got = files.rgb_float(pixels, threads=threads)
        assert got.dtype == np.float32 and got.shape == (301, 257, 3)
        assert np.array_equal(got.view(np.uint32), want.view(np.uint32)), threads


def test_other_pixels_take_numpys_path(rng):
    for pixels in (rng.integers(0, 65536, (9, 7, 3), dtype=np.uint16),
                   rng.integers(0, 256, (9, 7, 1), dtype=np.uint8),
                   rng.random((9, 7, 4), dtype=np.float32)):
        assert np.array_equal(files.rgb_float(pixels), _numpy(pixels))
    strided = rng.integers(0, 256, (9, 14, 4), dtype=np.uint8)[:, ::2]  # not contiguous
    assert np.array_equal(files.rgb_float(strided), _numpy(strided))


def test_bad_photo_arguments_are_refused(rng):
    out = np.empty((4, 5, 3), np.float32)
    with pytest.raises(ValueError, match="3 or more channels"):
        native.photo_rgb(np.zeros((4, 5, 2), np.uint8), out, threads=1)
    with pytest.raises((TypeError, ValueError)):
        native.photo_rgb(np.zeros((4, 5, 3), np.float32), out, threads=1)
    with pytest.raises(ValueError, match="shape"):
        native.photo_rgb(np.zeros((4, 6, 3), np.uint8), out, threads=1)
