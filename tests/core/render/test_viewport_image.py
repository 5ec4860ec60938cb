"""The viewport's images of a render (`renderer.viewport_image`, native/src/viewport.c) against
the float64 formula (tests/reference.py `window_depth`): RGBA interleaved and both images
flipped bottom to top exactly; depth-buffer values within half a float32 ulp of the float64
value (each is computed in double and rounded once); any thread count, the same bits."""

from __future__ import annotations

import numpy as np
import pytest

from addon.core.render.renderer import RenderResult, viewport_image
from tests import reference as ref


def _perspective(near: float, far: float) -> np.ndarray:
    return np.array([[1.2, 0, 0.1, 0], [0, 1.6, -0.05, 0],
                     [0, 0, -(far + near) / (far - near), -2 * far * near / (far - near)],
                     [0, 0, -1, 0]])


def _orthographic(near: float, far: float) -> np.ndarray:
    return np.array([[0.3, 0, 0, 0.02], [0, 0.4, 0, -0.1],
                     [0, 0, -2 / (far - near), -(far + near) / (far - near)], [0, 0, 0, 1]])


def _render(rng, height: int, width: int) -> RenderResult:
    depth = rng.uniform(-5, 150, (height, width)).astype(np.float32)
    depth[rng.random((height, width)) < 0.2] = np.inf  # nothing hit
    depth[0, :3] = [0.0, -0.0, np.float32(1e-30)]
    return RenderResult(rng.normal(size=(height, width, 3)).astype(np.float32),
                        rng.random((height, width), dtype=np.float32), depth)


@pytest.mark.parametrize("projection", [_perspective(0.1, 100.0), _orthographic(-50.0, 50.0)],
                         ids=["perspective", "orthographic"])
def test_viewport_image_matches_the_float64_formula(rng, projection):
    result = _render(rng, 67, 93)
    rgba, depth = viewport_image(result, projection, threads=1)
    assert rgba.dtype == depth.dtype == np.float32 and rgba.shape == (67, 93, 4)
    assert np.array_equal(rgba[::-1, :, :3], result.rgb)
    assert np.array_equal(rgba[::-1, :, 3], result.alpha)
    want = ref.window_depth(result.depth, projection)[::-1]
    assert np.all((depth >= 0) & (depth <= 1))
    assert np.all(depth[result.depth[::-1] == np.inf] == 1.0)
    err = np.abs(depth.astype(np.float64) - want)
    assert np.all(err <= 0.5 * np.spacing(np.float32(want)).astype(np.float64) + 1e-300)
    assert 0.05 < np.mean((want > 0) & (want < 1))  # a real mix of clipped and inside values


def test_viewport_image_is_the_same_on_any_thread_count(rng):
    result = _render(rng, 700, 300)  # several chunks of rows
    first = viewport_image(result, _perspective(0.01, 1000.0), threads=1)
    for threads in (2, 3, 0):
        other = viewport_image(result, _perspective(0.01, 1000.0), threads=threads)
        assert all(np.array_equal(a, b) for a, b in zip(first, other)), threads


def test_viewport_image_refuses_overlapping_outputs(rng):
    from addon.core import native

    result = _render(rng, 8, 8)
    rgba = np.empty((8, 8, 4), np.float32)
    with pytest.raises(ValueError, match="overlap"):
        native.viewport_image(result.rgb, result.alpha, result.depth, np.ones(4), rgba,
                              result.alpha, threads=1)  # out_depth over the alpha read
    with pytest.raises(ValueError, match="non-finite"):
        native.viewport_image(result.rgb, result.alpha, result.depth,
                              np.array([1.0, np.nan, 0.0, 1.0]), rgba,
                              np.empty((8, 8), np.float32), threads=1)
