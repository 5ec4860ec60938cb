"""The compositor's footprint masks skip only evaluations that add nothing: a render is identical
bit for bit to its slow twin (`exhaustive=True`, every Gaussian over the whole bounding span of
each of its tiles, the pre-mask algorithm), with fewer evaluations. The twin is itself held
against the float64 reference by every accuracy test; here the two native paths must agree
exactly, on ordinary scenes and on the hard cases where float rounding is largest (needle-thin,
huge, far from the origin, extreme fields of view, stacked, with a mesh layer)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from addon.core.render import renderer as api
from addon.core import splat_io
from addon.core.cameras import Camera
from addon.core.gaussians import Gaussians
from tests.scenes import playbot_camera, random_camera, random_gaussians, random_mesh_layer


def _assert_twins(gaussians: Gaussians, camera: Camera, **options) -> tuple[int, int]:
    """Masked and exhaustive renders are identical; returns their evaluation counts."""
    fast = api.render(gaussians, camera, **options)
    slow = api.render(gaussians, camera, exhaustive=True, **options)
    for name, x, y in zip(("rgb", "alpha", "depth"), fast, slow):
        assert np.array_equal(x, y, equal_nan=True), f"{name} differs, {sorted(options)}"
    assert fast.stats["evaluations"] <= slow.stats["evaluations"]
    return fast.stats["evaluations"], slow.stats["evaluations"]


def _identity_camera(width=64, height=48, f=40.0) -> Camera:
    return Camera(np.eye(4), f, f, width / 2, height / 2, width, height)


def _front(rng, n, depth=(3.0, 6.0), spread=1.0):
    return np.column_stack([rng.uniform(-spread, spread, (n, 2)), rng.uniform(*depth, n)])


@pytest.mark.parametrize("antialiased", [False, True])
def test_random_scenes_with_and_without_mesh(rng, antialiased):
    gaussians = random_gaussians(rng, 3000, 1)
    camera = random_camera(rng, 173, 111)  # partial edge tiles on both axes
    mesh_rgba, mesh_depth = random_mesh_layer(rng, camera.width, camera.height)
    fast, slow = _assert_twins(gaussians, camera, antialiased=antialiased)
    assert fast < 0.9 * slow  # the masks do skip work
    _assert_twins(gaussians, camera, antialiased=antialiased, mesh_rgba=mesh_rgba,
                  mesh_depth=mesh_depth, background=np.float32([0.2, 0.3, 0.4]), threads=3)


def test_needle_thin_point_like_and_huge(rng):
    n = 300
    log_scales = rng.uniform(-4, -1, (n, 3))
    log_scales[:100, 1:] = -20.0  # needles: long in x only, any rotation
    log_scales[100:150] = -20.0   # points: the dilation alone
    log_scales[150:160] = 8.0     # huge: cover the image
    log_scales[160:170, :2] = 8.0
    log_scales[170:200, 0] = rng.uniform(0, 3, 30)  # long, thin streaks across many tiles
    log_scales[170:200, 1:] = -9.0
    g = Gaussians(_front(rng, n), log_scales, rng.normal(size=(n, 4)), rng.uniform(-4, 6, n),
                  rng.normal(0, 0.5, (n, 1, 3)))
    for camera in (_identity_camera(), _identity_camera(200, 150, 170.0)):
        _assert_twins(g, camera)
        _assert_twins(g, camera, antialiased=True)


def test_far_from_the_origin(rng):
    offset = np.array([1.0e5, -0.7e5, 1.3e5])
    g = random_gaussians(rng, 2000, 1, radius=500.0, stray=0.0)
    g.log_scales[:] = rng.uniform(np.log(20), np.log(300), g.log_scales.shape)
    g.means = (g.means.astype(np.float64) + offset).astype(np.float32)
    camera = random_camera(rng, 120, 90, target=offset, distance=2000.0)
    _assert_twins(g, camera)


@pytest.mark.parametrize("f", [2.0, 4000.0])
def test_extreme_fields_of_view(rng, f):
    n = 400
    g = Gaussians(_front(rng, n, depth=(0.5, 8.0), spread=5.0), rng.uniform(-5, -0.5, (n, 3)),
                  rng.normal(size=(n, 4)), rng.uniform(-2, 5, n), rng.normal(0, 0.5, (n, 1, 3)))
    _assert_twins(g, _identity_camera(97, 61, f))


def test_stacked_until_the_pixels_stop(rng):
    # 3000 nearly opaque Gaussians on one spot: the pixels stop early, later ones add nothing.
    n = 3000
    means = np.column_stack([rng.normal(0, 0.02, (n, 2)), np.linspace(3, 6, n)])
    g = Gaussians(means, rng.uniform(-3, -1.5, (n, 3)), rng.normal(size=(n, 4)),
                  rng.uniform(2, 6, n), rng.normal(0, 0.5, (n, 1, 3)))
    fast, slow = _assert_twins(g, _identity_camera())
    assert fast < slow


@pytest.mark.parametrize("size", [(1, 1), (17, 5), (16, 16)])
def test_tiny_images(rng, size):
    g = random_gaussians(rng, 500, 0)
    _assert_twins(g, random_camera(rng, *size))


def test_real_capture(shared_data: Path):
    gaussians = splat_io.load(shared_data / "splats" / "playbot_125k_sh2.ply")
    fast, slow = _assert_twins(gaussians, playbot_camera())
    assert fast < 0.8 * slow
