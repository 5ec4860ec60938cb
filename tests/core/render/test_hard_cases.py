"""Hard numerical cases (docs/development.md, "Tests"), each with the behaviour it must have, compared
with the float64 reference where that is meaningful. Tolerances: tests/checks.py unless stated."""

from __future__ import annotations

import math

import numpy as np
import pytest

from addon.core.render import renderer as api
from addon.core.cameras import Camera
from addon.core.gaussians import Gaussians
from tests import reference as ref
from tests.checks import assert_images_match, assert_projection_matches, compare_renders
from tests.scenes import random_camera, random_gaussians, random_scene


def _camera(width=64, height=48, f=40.0, cx=None, cy=None, fy=None):
    """Identity pose: world = camera space (x right, y down, z forward)."""
    return Camera(np.eye(4), f, f if fy is None else fy, width / 2 if cx is None else cx,
                  height / 2 if cy is None else cy, width, height)


def _gaussians(means, log_scales=-1.0, quats=(1, 0, 0, 0), logits=2.0, sh=None, degree=0):
    means = np.asarray(means, np.float64).reshape(-1, 3)
    n = len(means)
    if sh is None:
        sh = np.zeros((n, (degree + 1) ** 2, 3))
        sh[:, 0] = np.linspace(-1, 1, 3 * n).reshape(n, 3)
    return Gaussians(means, np.broadcast_to(log_scales, (n, 3)), np.broadcast_to(quats, (n, 4)),
                     np.broadcast_to(logits, (n,)), sh)


def _check(gaussians, camera, **options):
    """Native project and render against the reference; returns the native render."""
    project_options = {k: v for k, v in options.items() if k in ("near", "antialiased", "sh_degree")}
    want_p = ref.project_scene(gaussians, camera, **project_options)
    assert_projection_matches(api.project(gaussians, camera, **project_options), want_p,
                              gaussians.means, *ref.camera_args(camera)[:5])
    got = api.render(gaussians, camera, **options)
    assert_images_match(got, ref.render_scene(gaussians, camera, **options))
    return got


# ---------------------------------------------------------------- near plane


def test_near_plane_default():
    # near = 0.01: z = 0.0101 kept, z = 0.0099 culled (float32 of both is clearly to one side).
    g = _gaussians([[0, 0, 0.0101], [0, 0, 0.0099], [0.1, 0, 1.0]], log_scales=-6)
    p = api.project(g, _camera())
    np.testing.assert_array_equal(p.valid, [True, False, True])
    _check(g, _camera())


@pytest.mark.parametrize("near", [0.125, 1.0, 2.5])
def test_near_plane_custom(near):
    # z exactly at near (representable in float32 and float64 alike) is kept; 0.1% in front is
    # kept, 0.1% behind and behind the camera are culled; the parameter is honoured.
    zs = [near, near * 1.001, near * 0.999, -near, 3 * near]
    g = _gaussians([[0.01 * i, 0, z] for i, z in enumerate(zs)], log_scales=math.log(near) - 3)
    cam = _camera()
    p = api.project(g, cam, near=near)
    np.testing.assert_array_equal(p.valid, [True, True, False, False, True])
    np.testing.assert_array_equal(p.depth[~p.valid], 0)
    _check(g, cam, near=near)
    # Culling depends on the near parameter: with near halved the third comes back.
    np.testing.assert_array_equal(api.project(g, cam, near=near / 2).valid, [True, True, True, False, True])


def test_gaussians_straddling_the_near_plane(rng):
    # Large Gaussians whose means lie just in front of and just behind the near plane: the ones
    # in front cover much of the image with extreme projected sizes; behind ones never count.
    n = 60
    near = 0.5
    z = near * (1 + rng.uniform(-0.05, 0.05, n))
    xy = rng.uniform(-0.4, 0.4, (n, 2)) * z[:, None]
    g = _gaussians(np.column_stack([xy, z]), log_scales=rng.uniform(-4, -1.5, (n, 3)),
                   quats=rng.normal(size=(n, 4)), logits=rng.normal(0, 2, n),
                   sh=rng.normal(0, 0.5, (n, 1, 3)))
    got = _check(g, _camera(), near=near, background=np.float32([0.1, 0.2, 0.3]))
    assert np.isfinite(got.rgb).all()


# ---------------------------------------------------------------- guard band


@pytest.mark.parametrize("antialiased", [False, True])
def test_far_outside_the_view_guard_band(rng, antialiased):
    # W = 64, f = 32: the clamp on x/z in J is (64 - 32) / 32 + 0.3 * 1 = 1.3. Means at
    # |x/z| = 1.4..6 (outside the image and the guard band), large enough that their tails
    # (with the clamped J) reach into the image; and some very far out (x/z up to 1000).
    cam = _camera(64, 48, 32.0)
    n = 80
    z = rng.uniform(2, 6, n)
    ratio = rng.uniform(1.4, 6, n) * rng.choice([-1, 1], n)
    ratio[:10] = rng.uniform(50, 1000, 10) * rng.choice([-1, 1], 10)
    other = rng.uniform(-0.5, 0.5, n)
    swap = rng.random(n) < 0.5  # out on x or on y
    x = np.where(swap, other, ratio) * z
    y = np.where(swap, ratio, other) * z
    g = _gaussians(np.column_stack([x, y, z]), log_scales=rng.uniform(-0.5, 1.0, (n, 3)),
                   quats=rng.normal(size=(n, 4)), logits=rng.uniform(0, 4, n),
                   sh=rng.normal(0, 0.5, (n, 1, 3)))
    p = ref.project_scene(g, cam)
    # Every mean projects beyond the guard band (x/z > 1.3: 41.6 px from cx; y/z > 0.975: 31.2 px).
    beyond = (np.abs(p["xy"][:, 0] - 32) > 41.6) | (np.abs(p["xy"][:, 1] - 24) > 31.2)
    assert beyond.all()
    got = _check(g, cam, antialiased=antialiased)
    assert got.alpha.max() > 0.05  # the tails do reach the image


# ---------------------------------------------------------------- scales and rotations


@pytest.mark.parametrize("antialiased", [False, True])
def test_needle_thin_and_point_like(rng, antialiased):
    # log_scale -20 on two axes (a needle, up to ~10 px long), on all three (a point: the 2D
    # covariance is the 0.3 px^2 dilation alone).
    n = 40
    means = np.column_stack([rng.uniform(-1, 1, (n, 2)), rng.uniform(3, 5, n)])
    log_scales = np.full((n, 3), -20.0)
    log_scales[: n // 2, 0] = rng.uniform(-3, -1, n // 2)
    g = _gaussians(means, log_scales=log_scales, quats=rng.normal(size=(n, 4)),
                   logits=rng.uniform(0, 5, n), sh=rng.normal(0, 0.5, (n, 1, 3)))
    got = _check(g, _camera(), antialiased=antialiased)
    if not antialiased:
        assert got.alpha.max() > 0.5
    point = api.project(g.subset(slice(n // 2, n)), _camera())
    np.testing.assert_allclose(point.conic[:, [0, 2]], 1 / 0.3, rtol=1e-5)
    np.testing.assert_allclose(point.conic[:, 1], 0, atol=1e-5)


@pytest.mark.parametrize("antialiased", [False, True])
def test_huge_scales(rng, antialiased):
    # log_scale +8 (sigma ~ 3000 units, ~20000 px): each covers the whole image with
    # alpha ~ its opacity; mixed with ordinary ones.
    cam = _camera(40, 30, 30.0)
    n = 12
    means = np.column_stack([rng.uniform(-1, 1, (n, 2)), rng.uniform(3, 6, n)])
    log_scales = rng.uniform(-2.5, -1, (n, 3))
    log_scales[:3] = 8.0
    log_scales[3, :2] = 8.0  # huge in two axes, ordinary in the third
    g = _gaussians(means, log_scales=log_scales, quats=rng.normal(size=(n, 4)),
                   logits=rng.uniform(-3, 0, n), sh=rng.normal(0, 0.5, (n, 1, 3)))
    got = _check(g, cam, antialiased=antialiased)
    assert got.alpha.min() > 0.03  # covered everywhere


def test_zero_and_unnormalised_quaternions(rng):
    g, cam = random_scene(rng, 200, 48, 40, 1)
    identity = g.copy()
    identity.quats[:] = [1, 0, 0, 0]
    zero = g.copy()
    zero.quats[:] = 0
    a, b = api.render(identity, cam), api.render(zero, cam)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)  # zero is the identity, exactly
    _check(zero, cam)

    scaled = g.copy()
    scaled.quats *= np.float32(37)
    tiny = g.copy()
    tiny.quats *= np.float32(1e-6)
    base = api.render(g, cam)
    for other in (scaled, tiny):
        # Normalised on use: the same rotation up to the rounding of the normalisation, which
        # can flip a threshold at a few pixels (seed 1271355671: 3 of 1,920 by 0.0019; about
        # one scene in 400), as in any two frames of one scene.
        compare_renders(base, api.render(other, cam), atol=1e-5)
    _check(scaled, cam)


# ---------------------------------------------------------------- opacity extremes


def test_opacity_logit_minus_30_contributes_nothing(rng):
    g, cam = random_scene(rng, 200, 48, 40, 2)
    g.opacity_logits[:] = -30
    background = np.float32([0.3, 0.6, 0.9])
    got = api.render(g, cam, background=background)
    np.testing.assert_array_equal(got.rgb, np.broadcast_to(background, got.rgb.shape))
    np.testing.assert_array_equal(got.alpha, 0)
    assert np.isposinf(got.depth).all()


def test_opacity_logit_plus_30_clamps_at_0_99():
    # One opaque Gaussian centred on pixel (10, 7): alpha there is exactly the 0.99 clamp.
    cam = _camera(21, 15, 20.0)
    g = _gaussians([[0, 0, 4]], log_scales=-1.5, logits=30.0, sh=np.float32([[[0.5, 0.5, 0.5]]]))
    got = _check(g, cam)
    assert abs(got.alpha[7, 10] - 0.99) < 1e-6
    assert got.alpha.max() <= 0.99 + 1e-6
    # Two stacked: T = 0.01 * 0.01 = 1e-4 is not below 1e-4 ... within float rounding of the
    # stop, so use three: the third would take T to 1e-6 and is left out.
    g3 = _gaussians([[0, 0, 4], [0, 0, 5], [0, 0, 6]], log_scales=-1.5, logits=30.0)
    got = api.render(g3, cam)
    want = ref.render_scene(g3, cam)
    assert 1 - got.alpha[7, 10] >= 1e-4 * (1 - 1e-3)
    assert_images_match(got, want, max_ambiguous=0.05)


# ---------------------------------------------------------------- stacking


@pytest.mark.parametrize("kind", ["spread", "same_depth", "faint"])
def test_3000_gaussians_stacked_on_one_pixel(rng, monkeypatch, kind):
    # 3000 Gaussians centred on pixel (4, 3) of a 9x7 image. Transmittance would underflow
    # without the stop (0.98^3000 ~ 1e-27): the result equals the reference, alpha stays <= 1
    # and everything is finite.
    #   spread: depths 3..9, sigma 13..67 px (alpha ~ opacity over the whole image, so no
    #           pixel sits at the 1/255 skip), opacities 0.02..0.98;
    #   same_depth: the same at one depth (index order decides, exactly, on both sides);
    #   faint: sigma ~1..3 px, opacities 0.007..0.05: hundreds blend before the stop at the
    #          centre; off-centre pixels see thousands at the 1/255 skip, so only the centre
    #          pixel is sure to be unambiguous.
    n = 3000
    cam = _camera(9, 7, 10.0)
    z = np.full(n, 4.0) if kind == "same_depth" else rng.uniform(3, 9, n)
    means = np.column_stack([rng.normal(0, 0.005, n) * z, rng.normal(0, 0.005, n) * z, z])
    if kind == "same_depth":
        means[:, :2] = [0.02, -0.01]
    faint = kind == "faint"
    g = _gaussians(means, log_scales=rng.uniform(-0.5, 0, (n, 3)) if faint else rng.uniform(2.5, 3, (n, 3)),
                   quats=rng.normal(size=(n, 4)),
                   logits=rng.uniform(-5, -3, n) if faint else rng.uniform(-4, 4, n),
                   sh=rng.normal(0, 0.5, (n, 4, 3)), degree=1)
    background = np.float32([1, 1, 1])
    got = api.render(g, cam, background=background)
    want = ref.render_scene(g, cam, background=background)
    assert np.isfinite(got.rgb).all() and np.isfinite(got.alpha).all()
    assert got.alpha.max() <= 1 and (1 - got.alpha[3, 4]) >= 1e-4 * (1 - 1e-3)
    assert want["alpha"][3, 4] > 0.99  # T is small at the centre, the stop was reached
    if faint:
        assert_images_match(got, want, max_ambiguous=1.0)
        # The centre pixel blends hundreds of faint Gaussians: its stop may land within float32
        # rounding of 1e-4 (T shrinks ~3% a step, so ~2% of the time). Then native must equal
        # the reference with the stop threshold nudged one way or the other.
        matches = []
        for t_min in (ref.T_MIN, ref.T_MIN * (1 - 1e-3), ref.T_MIN * (1 + 1e-3)):
            monkeypatch.setattr(ref, "T_MIN", t_min)
            other = ref.render_scene(g, cam, background=background)
            matches.append(np.abs(got.rgb[3, 4] - other["rgb"][3, 4]).max() <= 1e-4
                           and abs(got.alpha[3, 4] - other["alpha"][3, 4]) <= 1e-4)
        assert matches[0] or (want["ambiguous"][3, 4] and any(matches)), matches
    else:
        assert_images_match(got, want, max_ambiguous=0.05)


# ---------------------------------------------------------------- far from the origin


def test_scene_far_from_the_origin(rng, monkeypatch):
    # Means and camera translated by ~1e5. float32 means there are quantised to 2^-7 ~ 0.008
    # units (up to 0.0068 units off in 3D), so the scene is built at a scale where that is
    # small: ~1000 units across, seen from ~2000 units (depths 1500..2500, 15..35 units a
    # pixel), sigmas of 120..300 units (3.4..20 px), so the means move by <= 4.5e-4 px.
    #  - Native equals the reference on the same (quantised) float32 inputs: its projection is
    #    exact far from the origin, not just its compositing.
    #  - And equals the untranslated render within 2e-3 (1.5e-5 seen): a 4.5e-4 px shift moves
    #    alpha by at most 0.6 / sigma_px * 4.5e-4 ~ 8e-5 per Gaussian. Except where the shift
    #    takes alpha across the 1/255 skip (alpha within 3.3 / sigma_px * 4.5e-4 ~ 4.4e-4
    #    relative of it) or T across the stop: those pixels are left out with margins of 1e-3.
    width, height = 96, 80
    offset = np.array([1.0e5, -0.7e5, 1.3e5])
    n = 40
    cam = random_camera(rng, width, height, distance=2000.0)
    # The quantisation also moves depths by up to ~0.007 units, which can swap two Gaussians
    # whose depths are closer than that: keep every pair of depths 0.05 apart, so the depth
    # order is the same in both scenes (otherwise a swap changes a pixel by up to ~0.01).
    while True:
        g = random_gaussians(rng, n, 1, radius=500.0, stray=0.0)
        depths = g.means.astype(np.float64) @ cam.world_to_camera[2, :3] + cam.world_to_camera[2, 3]
        if np.diff(np.sort(depths)).min() > 0.05:
            break
    g.log_scales[:] = rng.uniform(np.log(120), np.log(300), (n, 3))
    far_g = g.copy()
    far_g.means = (g.means.astype(np.float64) + offset).astype(np.float32)
    w2c = cam.world_to_camera.copy()
    w2c[:3, 3] -= w2c[:3, :3] @ offset  # the same camera, moved with the scene
    far_cam = Camera(w2c, cam.fx, cam.fy, cam.cx, cam.cy, width, height)
    assert 0.001 < np.abs(far_g.means - offset - g.means).max() < 0.004

    far = _check(far_g, far_cam)
    near = _check(g, cam)
    assert near.alpha.mean() > 0.1
    monkeypatch.setattr(ref, "AMBIGUOUS_ALPHA", 1e-3)
    monkeypatch.setattr(ref, "AMBIGUOUS_T", 1e-3)
    assert_images_match(far, ref.render_scene(g, cam), rgb_atol=2e-3, alpha_atol=2e-3,
                        depth_rtol=2e-3, max_ambiguous=0.02)
    # Where a skip or the stop flips, a pixel moves by one Gaussian's alpha T c <= ~0.02.
    assert np.abs(far.rgb - near.rgb).max() < 0.05


# ---------------------------------------------------------------- field of view and image size


def test_extreme_wide_field_of_view(rng):
    # fx tiny: ~170 degrees across (tan 85 = 11.4), Gaussians over the whole frustum.
    width, height = 64, 48
    f = width / 2 / math.tan(math.radians(85))
    cam = _camera(width, height, f)
    n = 100
    z = rng.uniform(0.5, 5, n)
    means = np.column_stack([rng.uniform(-13, 13, n) * z, rng.uniform(-13, 13, n) * z, z])
    g = _gaussians(means, log_scales=np.log(z)[:, None] + rng.uniform(-1, 0.5, (n, 3)),
                   quats=rng.normal(size=(n, 4)), logits=rng.normal(0, 2, n),
                   sh=rng.normal(0, 0.4, (n, 9, 3)), degree=2)
    got = _check(g, cam)
    assert got.alpha.mean() > 0.1


def test_extreme_telephoto(rng):
    # fx huge: 0.5 degrees across; Gaussians 100..200 units away near the axis.
    width, height = 64, 48
    f = width / 2 / math.tan(math.radians(0.25))
    cam = _camera(width, height, f)
    n = 200
    z = rng.uniform(100, 200, n)
    means = np.column_stack([rng.uniform(-0.006, 0.006, (n, 2)) * z[:, None], z])
    g = _gaussians(means, log_scales=np.log(z * 2e-4)[:, None] + rng.uniform(-1, 1, (n, 3)),
                   quats=rng.normal(size=(n, 4)), logits=rng.normal(0, 2, n),
                   sh=rng.normal(0, 0.4, (n, 4, 3)), degree=1)
    got = _check(g, cam)
    assert got.alpha.mean() > 0.1


@pytest.mark.parametrize("size", [(1, 1), (17, 13), (1, 40), (33, 1)])
def test_tiny_and_odd_image_sizes(rng, size):
    width, height = size
    g, cam = random_scene(rng, 300, width, height, 3)
    _check(g, cam, background=rng.random(3).astype(np.float32), antialiased=bool(rng.integers(2)))


# ---------------------------------------------------------------- bad values and empty input


@pytest.mark.parametrize("field, index, value", [
    ("means", (5, 1), np.nan), ("means", (0, 2), np.inf), ("log_scales", (7, 0), np.inf),
    ("log_scales", (3, 2), np.nan), ("quats", (2, 0), np.nan), ("opacity_logits", (4,), np.nan),
    ("opacity_logits", (1,), np.inf), ("sh", (6, 0, 2), np.nan), ("sh", (9, 3, 0), -np.inf),
])
def test_non_finite_gaussians_raise(rng, field, index, value):
    g, cam = random_scene(rng, 20, 32, 24, 1)
    getattr(g, field)[index] = value
    with pytest.raises(ValueError, match="non-finite"):
        api.render(g, cam)
    with pytest.raises(ValueError, match="non-finite"):
        api.project(g, cam)
    if field != "means":  # even when that Gaussian would be culled (behind the camera)
        g.means[index[0]] = cam.centre - 5 * cam.world_to_camera[2, :3]
        assert (cam.world_to_camera @ np.append(g.means[index[0]], 1))[2] < 0
        with pytest.raises(ValueError, match="non-finite"):
            api.render(g, cam)


@pytest.mark.parametrize("value", [np.nan, np.inf])
def test_non_finite_camera_raises(value):
    matrix = np.eye(4)
    matrix[1, 3] = value
    with pytest.raises(ValueError, match="non-finite"):
        Camera(matrix, 30, 30, 16, 12, 32, 24)
    cam = _camera(32, 24)
    cam.world_to_camera = matrix  # past the Camera check: the renderer must refuse it too
    g = _gaussians([[0, 0, 3]])
    with pytest.raises(ValueError, match="non-finite"):
        api.render(g, cam)
    cam = _camera(32, 24)
    cam.fx = value
    with pytest.raises(ValueError, match="non-finite"):
        api.render(g, cam)


def test_empty_gaussians_render_the_background():
    cam = _camera(19, 11)
    background = np.float32([0.25, 0.5, 0.75])
    for degree in (0, 3):
        got = api.render(Gaussians.empty(degree), cam, background=background)
        np.testing.assert_array_equal(got.rgb, np.broadcast_to(background, (11, 19, 3)))
        np.testing.assert_array_equal(got.alpha, 0)
        assert np.isposinf(got.depth).all()
        got = api.render(Gaussians.empty(degree), cam)
        np.testing.assert_array_equal(got.rgb, 0)
        p = api.project(Gaussians.empty(degree), cam)
        assert p.xy.shape == (0, 2) and p.valid.shape == (0,)


def test_empty_gaussians_with_mesh_layer(rng):
    cam = _camera(19, 11)
    mesh_rgba = np.zeros((11, 19, 4), np.float32)
    mesh_rgba[..., 3] = rng.random((11, 19))
    mesh_rgba[..., :3] = mesh_rgba[..., 3:] * rng.random((11, 19, 3))
    mesh_depth = rng.uniform(1, 5, (11, 19)).astype(np.float32)
    got = api.render(Gaussians.empty(), cam, mesh_rgba=mesh_rgba, mesh_depth=mesh_depth)
    np.testing.assert_allclose(got.rgb, mesh_rgba[..., :3], rtol=0, atol=1e-7)
    np.testing.assert_allclose(got.alpha, mesh_rgba[..., 3], rtol=0, atol=1e-7)
    np.testing.assert_allclose(got.depth, mesh_depth, rtol=1e-6)


def test_opaque_mesh_in_front_hides_every_gaussian(rng):
    g, cam = random_scene(rng, 200, 48, 40, 1)
    mesh_rgba = np.ones((40, 48, 4), np.float32) * np.float32([0.2, 0.4, 0.6, 1.0])
    mesh_depth = np.full((40, 48), 0.005, np.float32)  # nearer than the near plane (0.01)
    got = api.render(g, cam, mesh_rgba=mesh_rgba, mesh_depth=mesh_depth,
                     background=np.float32([1, 0, 0]))
    np.testing.assert_array_equal(got.rgb, np.broadcast_to(np.float32([0.2, 0.4, 0.6]), got.rgb.shape))
    np.testing.assert_array_equal(got.alpha, 1)
    np.testing.assert_array_equal(got.depth, np.float32(0.005))
