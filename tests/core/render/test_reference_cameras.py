"""Checks of the float64 reference's orthographic and panoramic cameras (tests/reference.py,
`camera_model_project`) with no native code: an analytic orthographic Gaussian, the orthographic
camera as the limit of a pinhole moved far away, and where each panorama puts what lies ahead,
to the right and above (Blender's conventions, docs/conventions.md "Cameras beyond the
pinhole")."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests import reference as ref
from tests.scenes import random_camera, random_gaussians


def _one(mean, log_scale, logit, sh0=(0.3, 0.2, 0.1)):
    return (np.array([mean], np.float32), np.full((1, 3), log_scale, np.float32),
            np.array([[1, 0, 0, 0]], np.float32), np.array([logit], np.float32),
            np.array([[sh0]], np.float32))


def test_ortho_isotropic_gaussian_is_analytic_and_independent_of_depth():
    width, height, f, sigma, logit = 31, 23, 6.0, 0.4, 1.1
    for z in (-3.0, 2.0, 50.0):
        out = ref.render(*_one((0.5, -0.25, z), math.log(sigma), logit), np.eye(4), f, f, 15.0,
                         11.0, width, height, model="ORTHO", near=-10.0)
        s = np.float64(np.float32(math.log(sigma)))
        var = (f * math.exp(s)) ** 2 + 0.3
        o = 1 / (1 + math.exp(-np.float64(np.float32(logit))))
        px, py = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
        r2 = (px - (f * 0.5 + 15)) ** 2 + (py - (-f * 0.25 + 11)) ** 2
        alpha = np.minimum(0.99, o * np.exp(-0.5 * r2 / var))
        alpha = np.where(alpha >= 1 / 255, alpha, 0.0)
        np.testing.assert_allclose(out["alpha"], alpha, rtol=1e-12, atol=1e-15)
        assert np.allclose(out["depth"][alpha > 0], z)


def test_ortho_is_a_pinhole_moved_far_away(rng):
    # A pinhole camera moved back by D along its axis with its focal length scaled by D sees
    # the scene as the orthographic camera does, up to O(scene size / D) (positions, shapes and
    # the SH view direction); its depths are D more. Compared per Gaussian: images would order
    # the Gaussians by float32 depth keys, which tie at such depths.
    gaussians = random_gaussians(rng, 300, 3, stray=0.0)  # within 2.5 units: errors ~1e-5
    camera = random_camera(rng, 48, 40)
    ortho_f, distance = 48 / 6.0, 1e6
    far = camera.world_to_camera.copy()
    far[2, 3] += distance
    args = ref.gaussian_args(gaussians)
    pinhole = ref.project(*args, far, ortho_f * distance, ortho_f * distance, 24, 20, 48, 40)
    ortho = ref.project(*args, camera.world_to_camera, ortho_f, ortho_f, 24, 20, 48, 40,
                        model="ORTHO", near=-100.0)
    assert ortho["valid"].all() and pinhole["valid"].all()
    np.testing.assert_allclose(pinhole["xy"], ortho["xy"], atol=1e-3)
    np.testing.assert_allclose(pinhole["conic"], ortho["conic"], rtol=1e-4,
                               atol=1e-4 * np.abs(ortho["conic"]).max())
    np.testing.assert_allclose(pinhole["rgb"], ortho["rgb"], atol=1e-4)
    np.testing.assert_allclose(pinhole["opacity"], ortho["opacity"], rtol=1e-9)
    np.testing.assert_allclose(pinhole["depth"] - distance, ortho["depth"], atol=1e-6)


FULL = (-math.pi, math.pi, -math.pi / 2, math.pi / 2)
MODELS = [("EQUIRECTANGULAR", FULL), ("EQUIRECTANGULAR", (-1.0, 2.0, -0.5, 1.0)),
          ("FISHEYE_EQUIDISTANT", (math.radians(200),)),
          ("FISHEYE_EQUISOLID", (10.5, math.pi, 36.0, 24.0)), ("MIRRORBALL", ()),
          ("FISHEYE_LENS_POLYNOMIAL", (-1.1735e-05, -0.019989, -3.3525e-06, 3.0993e-06,
                                       -2.6065e-08, math.radians(120), 36.0, 24.0)),
          ("EQUIANGULAR_CUBEMAP_FACE", ()), ("CENTRAL_CYLINDRICAL", (-2.0, 2.5, -0.5, 1.5))]


@pytest.mark.parametrize("model, params", MODELS)
def test_panoramas_put_ahead_right_and_up_where_blender_does(model, params):
    # Camera frame: x right, y down, z ahead. Cycles' images: u to the right, v up.
    points = np.array([[0.0, 0.0, 1.0], [0.3, 0.0, 1.0], [0.0, -0.3, 1.0]])
    uv, shows = ref._cycles_uv(points, model, params)
    assert shows.all()
    ahead, right, up = uv
    if model == "EQUIRECTANGULAR":
        lon_min, lon_max, lat_min, lat_max = params
        np.testing.assert_allclose(ahead, [-lon_min / (lon_max - lon_min),
                                           -lat_min / (lat_max - lat_min)], atol=1e-12)
        np.testing.assert_allclose(right[0] - ahead[0], math.atan(0.3) / (lon_max - lon_min),
                                   rtol=1e-9)
        np.testing.assert_allclose(up[1] - ahead[1], math.atan(0.3) / (lat_max - lat_min),
                                   rtol=1e-9)
    elif model == "CENTRAL_CYLINDRICAL":  # u: the longitude; v: the height on the unit cylinder
        lon_min, lon_max, h_min, h_max = params
        np.testing.assert_allclose(ahead, [-lon_min / (lon_max - lon_min),
                                           -h_min / (h_max - h_min)], atol=1e-12)
        np.testing.assert_allclose(right - ahead, [math.atan(0.3) / (lon_max - lon_min), 0],
                                   rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(up - ahead, [0, 0.3 / (h_max - h_min)], rtol=1e-9, atol=1e-12)
    elif model == "EQUIANGULAR_CUBEMAP_FACE":  # equal angles, equal steps: 90 degrees across
        np.testing.assert_allclose(ahead, [0.5, 0.5], atol=1e-12)
        np.testing.assert_allclose(right, [0.5 + math.atan(0.3) / (math.pi / 2), 0.5], rtol=1e-9)
        np.testing.assert_allclose(up, [0.5, 0.5 + math.atan(0.3) / (math.pi / 2)], rtol=1e-9)
    else:
        np.testing.assert_allclose(ahead, [0.5, 0.5], atol=1e-12)
        assert right[0] > 0.5 and abs(right[1] - 0.5) < 1e-12
        assert up[1] > 0.5 and abs(up[0] - 0.5) < 1e-12
        theta = math.atan(0.3)
        if model == "FISHEYE_LENS_POLYNOMIAL":  # theta = -(k0 + k1 r + ... + k4 r^4), r in mm
            r = (right[0] - 0.5) * params[6]
            np.testing.assert_allclose(-np.polyval(params[4::-1], r), theta, rtol=1e-9)
            return
        radius = {"FISHEYE_EQUIDISTANT": lambda: 0.5 * 2 * theta / params[0],
                  "FISHEYE_EQUISOLID": lambda: 2 * params[0] * math.sin(theta / 2) / params[2],
                  "MIRRORBALL": lambda: 0.5 * math.sin(theta / 2)}[model]()
        np.testing.assert_allclose(right[0] - 0.5, radius, rtol=1e-9)


def test_equirectangular_directions_of_the_full_sphere():
    # Behind is the seam (u 0 or 1), straight up the top row, straight down the bottom one;
    # left is a quarter of the way across.
    uv, _ = ref._cycles_uv(np.array([[0.0, 0.0, -1.0], [0.0, -1.0, 0.0], [0.0, 1.0, 0.0],
                                     [-1.0, 0.0, 0.0]]), "EQUIRECTANGULAR", FULL)
    assert min(abs(uv[0, 0]), abs(uv[0, 0] - 1)) < 1e-12
    np.testing.assert_allclose([uv[1, 1], uv[2, 1]], [1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(uv[3], [0.25, 0.5], atol=1e-12)


def test_cubemap_face_and_cylinder_edges():
    # The face's corners are 45 degrees off its axis each way; it shows the half ahead only.
    uv, shows = ref._cycles_uv(np.array([[1.0, -1.0, 1.0], [-1.0, 1.0, 1.0], [0.0, 0.0, -1.0],
                                         [1.0, 0.0, -1e-3]]), "EQUIANGULAR_CUBEMAP_FACE", ())
    np.testing.assert_allclose(uv[:2], [[1.0, 1.0], [0.0, 0.0]], atol=1e-12)
    assert shows[:2].all() and not shows[2:].any()
    # The cylinder: straight up/down are not shown (infinitely high); behind is its seam; a
    # direction 45 degrees up is at height 1.
    full = (-math.pi, math.pi, -1.0, 1.0)
    uv, shows = ref._cycles_uv(np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [0.0, -1.0, 1.0],
                                         [-1.0, 1.0, 0.0]]), "CENTRAL_CYLINDRICAL", full)
    assert not shows[0] and shows[1:].all()
    assert min(abs(uv[1, 0]), abs(uv[1, 0] - 1)) < 1e-12
    np.testing.assert_allclose(uv[2:], [[0.5, 1.0], [0.25, 0.0]], atol=1e-12)


def test_fisheyes_show_nothing_beyond_their_field_of_view():
    behind = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, -0.1]])
    for model, params in MODELS[2:4]:
        _, shows = ref._cycles_uv(behind, model, params)
        assert not shows[0]
    _, shows = ref._cycles_uv(behind, "MIRRORBALL", ())
    assert not shows[0] and shows[1]  # the mirror ball sees all but straight behind


# ------------------------------------------------------------------------ depth of field

def _scene(rng, n=200):
    gaussians = random_gaussians(rng, n, 1, stray=0.0)
    return gaussians, random_camera(rng, 64, 48)


def test_depth_of_field_without_aperture_or_in_focus_changes_nothing(rng):
    gaussians, camera = _scene(rng)
    args = (*ref.gaussian_args(gaussians), *ref.camera_args(camera))
    sharp = ref.project(*args)
    np.testing.assert_array_equal(ref.project(*args, aperture=0.0, focus=3.0)["conic"],
                                  sharp["conic"])
    # A Gaussian exactly at the focus depth is not blurred.
    z = sharp["depth"][0]
    focused = ref.project(*args, aperture=0.05, focus=z)
    np.testing.assert_allclose(focused["conic"][0], sharp["conic"][0], rtol=1e-12)
    np.testing.assert_allclose(focused["opacity"][0], sharp["opacity"][0], rtol=1e-12)


@pytest.mark.parametrize("antialiased", [False, True])
def test_depth_of_field_keeps_each_gaussians_drawn_mass(rng, antialiased):
    # opacity * sqrt(det(conic^-1)) is what a Gaussian adds up to over the image (below the
    # 0.99 clamp); the blur spreads it without changing it.
    gaussians, camera = _scene(rng)
    args = (*ref.gaussian_args(gaussians), *ref.camera_args(camera))
    sharp = ref.project(*args, antialiased=antialiased)
    blurred = ref.project(*args, antialiased=antialiased, aperture=0.3, focus=4.0)

    def mass(p):
        a, b, c = p["conic"].T
        return p["opacity"] / np.sqrt(a * c - b * b)
    area = lambda p: 1 / np.sqrt(p["conic"][:, 0] * p["conic"][:, 2] - p["conic"][:, 1] ** 2)  # noqa: E731
    v = sharp["valid"]
    assert (area(blurred)[v] > area(sharp)[v] * 1.01).mean() > 0.5  # most are blurred
    # (antialiased: the raw Gaussian's mass; else the dilated one's, which is what such splats
    # draw)
    np.testing.assert_allclose(mass(blurred)[v], mass(sharp)[v], rtol=1e-9)


def test_depth_of_field_matches_a_thin_lens_average_of_pinholes(rng):
    # Independent: a thin lens is the average of pinhole views from points of its aperture,
    # each looking through the same focus plane (a shifted pinhole: the camera moved by `a` in
    # its own plane, its principal point moved by f a / focus). For one small, faint Gaussian
    # its averaged image has the blurred Gaussian's mass, centre and second moments (the disc's
    # blur is not a Gaussian, but has the same covariance).
    from tests.scenes import random_gaussians as rg
    g = rg(rng, 1, 0)
    mean = np.array([[0.1, -0.05, 5.0]], np.float32)
    args = (mean, np.full((1, 3), np.log(0.1), np.float32), np.float32([[1, 0, 0, 0]]),
            np.float32([2.0]), g.sh)  # opaque enough that the 1/255 cut-off trims little
    f, w, h, aperture, focus = 60.0, 64, 48, 0.5, 3.0  # a circle of confusion 4 px across
    blurred = ref.render(*args, np.eye(4), f, f, 32, 24, w, h, aperture=aperture, focus=focus)
    # Uniform samples of the aperture disc (a polar grid: exact moments of the disc).
    radii = aperture * np.sqrt((np.arange(24) + 0.5) / 24)
    angles = np.arange(32) * 2 * np.pi / 32
    total = np.zeros((h, w))
    for r in radii:
        for t in angles:
            a = np.array([r * np.cos(t), r * np.sin(t)])
            view = np.eye(4)
            view[:2, 3] = -a
            image = ref.render(*args, view, f, f, 32 + f * a[0] / focus, 24 + f * a[1] / focus, w, h)
            total += image["alpha"]
    total /= len(radii) * len(angles)
    ys, xs = np.mgrid[:h, :w] + 0.5

    def moments(alpha):
        m = alpha.sum()
        cx, cy = (alpha * xs).sum() / m, (alpha * ys).sum() / m
        return m, cx, cy, (alpha * (xs - cx) ** 2).sum() / m, (alpha * (ys - cy) ** 2).sum() / m
    got, want = moments(blurred["alpha"]), moments(total)
    np.testing.assert_allclose(got[:3], want[:3], rtol=0.02)
    np.testing.assert_allclose(got[3:], want[3:], rtol=0.08)  # the 1/255 cut-off trims both
