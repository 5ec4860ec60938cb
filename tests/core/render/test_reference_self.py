"""Checks of the float64 reference itself (tests/reference.py), with no native code: analytic
cases, an independent per-pixel pure-Python implementation, and the SH basis."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests import reference as ref
from tests.scenes import random_camera, random_gaussians, random_mesh_layer


def _identity_camera(width, height, f):
    return np.eye(4), f, f, width / 2, height / 2, width, height


def _one(mean, log_scale, logit, sh0, quat=(1, 0, 0, 0)):
    return (np.array([mean], np.float32), np.full((1, 3), log_scale, np.float32),
            np.array([quat], np.float32), np.array([logit], np.float32),
            np.array([[sh0]], np.float32))


# ---------------------------------------------------------------- analytic cases


@pytest.mark.parametrize("antialiased", [False, True])
def test_single_isotropic_gaussian_matches_analytic_alpha(antialiased):
    # An isotropic Gaussian on the optical axis: the 2D covariance is (f sigma / z)^2 I, plus
    # the 0.3 dilation, so alpha at offset d is o exp(-|d|^2 / (2 v)) (clamped, thresholded).
    width, height, f, z, sigma, logit = 21, 15, 20.0, 4.0, 0.5, 1.3
    sh0 = (0.2, -0.4, 1.1)
    args = _one((0.0, 0.0, z), math.log(sigma), logit, sh0)
    background = np.array([0.1, 0.7, 0.3])
    out = ref.render(*args, *_identity_camera(width, height, f), background=background,
                     antialiased=antialiased)
    s = np.float64(np.float32(math.log(sigma)))     # the float32 input, as the reference sees it
    var_raw = (f * math.exp(s) / z) ** 2
    var = var_raw + 0.3
    o = 1 / (1 + math.exp(-np.float64(np.float32(logit))))
    if antialiased:
        o *= var_raw / var                            # sqrt(det ratio) of a 2x2 isotropic matrix
    colour = np.maximum(ref.SH_C0 * np.float32(sh0).astype(np.float64) + 0.5, 0)
    px, py = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    r2 = (px - width / 2) ** 2 + (py - height / 2) ** 2
    alpha = np.minimum(0.99, o * np.exp(-0.5 * r2 / var))
    alpha = np.where(alpha >= 1 / 255, alpha, 0.0)
    assert (alpha == 0).any() and (alpha > 0).any()  # the footprint ends inside the image
    np.testing.assert_allclose(out["alpha"], alpha, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(out["rgb"], alpha[..., None] * colour
                               + (1 - alpha[..., None]) * background, rtol=1e-12, atol=1e-15)
    depth = np.where(alpha > 0, z, np.inf)
    np.testing.assert_array_equal(np.isinf(out["depth"]), np.isinf(depth))
    np.testing.assert_allclose(out["depth"][alpha > 0], z, rtol=1e-12)


def test_transmittance_stop_and_mesh_behind_a_stopped_pixel():
    # Four identical large Gaussians at depths 2, 3, 4, 5 with alpha 0.95 at the centre pixel:
    # T goes 0.05, 0.0025, 1.25e-4; the 4th would take it to 6.25e-6 < 1e-4, so it and all
    # after it are left out. The mesh (behind the 4th) still gets the T left.
    logit = math.log(0.95 / 0.05)
    n = 6
    means = np.array([[0, 0, 2 + i] for i in range(n)], np.float32)
    colours = np.eye(3)[np.arange(n) % 3] * 2.0
    args = (means, np.full((n, 3), 3.0, np.float32), np.tile(np.float32([1, 0, 0, 0]), (n, 1)),
            np.full(n, logit, np.float32), colours[:, None, :].astype(np.float32))
    cam = _identity_camera(1, 1, 1.0)
    mesh_rgba = np.array([[[0.2, 0.3, 0.4, 0.5]]])
    mesh_depth = np.array([[5.5]])
    out = ref.render(*args, *cam, mesh_rgba=mesh_rgba, mesh_depth=mesh_depth)
    proj = ref.project(*args, *cam)
    alpha = proj["opacity"][0] * math.exp(-0.5 * proj["conic"][0, 0] * 0)  # the pixel is the centre
    assert abs(alpha - 0.95) < 1e-6
    rgb_g = np.maximum(ref.SH_C0 * colours.astype(np.float32).astype(np.float64) + 0.5, 0)
    t = [1.0, 1 - alpha, (1 - alpha) ** 2, (1 - alpha) ** 3]
    want = sum(rgb_g[i] * alpha * t[i] for i in range(3)) + t[3] * mesh_rgba[0, 0, :3]
    np.testing.assert_allclose(out["rgb"][0, 0], want, rtol=1e-12)
    np.testing.assert_allclose(out["alpha"][0, 0], 1 - t[3] * 0.5, rtol=1e-12)
    wz = sum(alpha * t[i] * (2 + i) for i in range(3)) + t[3] * 0.5 * 5.5
    w = sum(alpha * t[i] for i in range(3)) + t[3] * 0.5
    np.testing.assert_allclose(out["depth"][0, 0], wz / w, rtol=1e-12)
    assert not out["ambiguous"].any()


def test_mesh_occludes_and_is_occluded():
    # One Gaussian at z = 4 over an opaque mesh: in front (mesh at 5) it covers the mesh,
    # behind (mesh at 3) it is hidden entirely.
    args = _one((0, 0, 4), 2.0, 2.0, (0.5, 0.5, 0.5))
    cam = _identity_camera(1, 1, 1.0)
    mesh_rgba = np.array([[[0.1, 0.2, 0.3, 1.0]]])
    front = ref.render(*args, *cam, mesh_rgba=mesh_rgba, mesh_depth=np.array([[5.0]]))
    a = 1 / (1 + math.exp(-2.0))
    c = ref.SH_C0 * np.float64(np.float32(0.5)) + 0.5
    np.testing.assert_allclose(front["rgb"][0, 0], a * c + (1 - a) * mesh_rgba[0, 0, :3], rtol=1e-6)
    np.testing.assert_allclose(front["depth"][0, 0], a * 4 + (1 - a) * 5, rtol=1e-6)
    assert front["alpha"][0, 0] == 1.0
    behind = ref.render(*args, *cam, mesh_rgba=mesh_rgba, mesh_depth=np.array([[3.0]]))
    np.testing.assert_array_equal(behind["rgb"][0, 0], mesh_rgba[0, 0, :3])
    assert behind["depth"][0, 0] == 3.0 and behind["alpha"][0, 0] == 1.0
    # An empty mesh pixel (alpha 0, depth inf) changes nothing.
    empty = ref.render(*args, *cam, mesh_rgba=np.zeros((1, 1, 4)), mesh_depth=np.full((1, 1), np.inf))
    plain = ref.render(*args, *cam)
    for key in ("rgb", "alpha", "depth"):
        np.testing.assert_array_equal(empty[key], plain[key])


def test_depth_order_is_stable_for_ties():
    # Two overlapping Gaussians at the same depth: index order decides who is in front.
    means = np.float32([[0, 0, 3], [0, 0, 3]])
    sh = np.float32([[[1, 0, 0]], [[0, 0, 1]]])
    base = (means, np.full((2, 3), 1.0, np.float32), np.tile(np.float32([1, 0, 0, 0]), (2, 1)),
            np.float32([1.0, 1.0]), sh)
    swapped = (means, base[1], base[2], base[3], sh[::-1].copy())
    cam = _identity_camera(1, 1, 1.0)
    a, b = ref.render(*base, *cam)["rgb"][0, 0], ref.render(*swapped, *cam)["rgb"][0, 0]
    assert a[0] > a[2] and b[2] > b[0]  # the first index wins either way


def test_zero_and_unnormalised_quaternions():
    q = np.float32([[0, 0, 0, 0], [1, 0, 0, 0], [0.3, -1.2, 0.5, 2.0], [0.3 * 37, -1.2 * 37, 0.5 * 37, 2.0 * 37]])
    r = ref.quat_to_rotmat(q)
    np.testing.assert_array_equal(r[0], np.eye(3))
    np.testing.assert_array_equal(r[1], np.eye(3))
    np.testing.assert_allclose(r[2], r[3], atol=1e-12)
    for m in r:
        np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-12)
        assert abs(np.linalg.det(m) - 1) < 1e-12
    # A 90 degree turn about z maps x to y.
    q90 = np.float64([[math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4)]])
    np.testing.assert_allclose(ref.quat_to_rotmat(q90)[0] @ [1, 0, 0], [0, 1, 0], atol=1e-15)


# ---------------------------------------------------------------- SH


def _sh_basis(dirs, degree):
    """(M, K) basis values: eval_sh on one-hot coefficients."""
    k = (degree + 1) ** 2
    values = []
    for i in range(k):
        sh = np.zeros((len(dirs), k, 3))
        sh[:, i, 0] = 1
        values.append(ref.eval_sh(sh, dirs, degree)[:, 0])
    return np.stack(values, 1)


def test_sh_degree0_is_c0_times_dc_plus_half(rng):
    n = 50
    g = random_gaussians(rng, n, 3)
    cam = random_camera(rng, 32, 24)
    args = ref.gaussian_args(g)
    p0 = ref.project_scene(g, cam, sh_degree=0)
    want = np.maximum(ref.SH_C0 * g.sh[:, 0].astype(np.float64) + 0.5, 0)
    v = p0["valid"]
    np.testing.assert_allclose(p0["rgb"][v], want[v], rtol=1e-15, atol=0)
    # Truncating to degree 1 equals giving degree-1 data.
    p1 = ref.project(*args[:4], g.sh[:, :4], *ref.camera_args(cam))
    np.testing.assert_array_equal(ref.project_scene(g, cam, sh_degree=1)["rgb"], p1["rgb"])


def test_sh_basis_is_orthonormal():
    # The real SH basis is orthonormal over the sphere: a typo in a constant breaks the norm,
    # a wrong basis expression breaks orthogonality. Fibonacci-sphere quadrature.
    m = 40_000
    i = np.arange(m) + 0.5
    zc = 1 - 2 * i / m
    phi = math.pi * (1 + 5 ** 0.5) * i
    dirs = np.stack([np.sqrt(1 - zc * zc) * np.cos(phi), np.sqrt(1 - zc * zc) * np.sin(phi), zc], 1)
    basis = _sh_basis(dirs, 3)
    gram = basis.T @ basis * (4 * math.pi / m)
    np.testing.assert_allclose(gram, np.eye(16), atol=1e-4)


def test_sh_degree1_follows_3dgs_signs():
    # 3DGS: -C1 y sh1 + C1 z sh2 - C1 x sh3.
    dirs = np.eye(3)
    basis = _sh_basis(dirs, 1)
    np.testing.assert_allclose(basis[:, 1:], -ref.SH_C1 * np.array([[0, 0, 1], [1, 0, 0], [0, -1, 0]]),
                               atol=1e-15)


# ---------------------------------------------------------------- an independent pure-Python twin


def _matmul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(len(b))) for j in range(len(b[0]))]
            for i in range(len(a))]


def _transpose(a):
    return [list(row) for row in zip(*a)]


def render_loop(means, log_scales, quats, logits, sh, viewmat, fx, fy, cx, cy, width, height,
                background=None, mesh_rgba=None, mesh_depth=None, near=0.01, antialiased=False):
    """Pixel by pixel, Gaussian by Gaussian, in plain Python floats (SH from ref.eval_sh)."""
    view = [[float(v) for v in row] for row in np.asarray(viewmat)]
    rv = [row[:3] for row in view[:3]]
    tv = [row[3] for row in view[:3]]
    centre = [-sum(rv[k][i] * tv[k] for k in range(3)) for i in range(3)]
    splats = []
    for g in range(len(means)):
        m = [float(v) for v in means[g]]
        w, x, y, z = (float(v) for v in quats[g])
        norm = math.sqrt(w * w + x * x + y * y + z * z)
        w, x, y, z = (1.0, 0.0, 0.0, 0.0) if norm == 0 else (w / norm, x / norm, y / norm, z / norm)
        rot = [[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
               [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
               [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]]
        s = [[math.exp(float(log_scales[g][i])) if i == j else 0.0 for j in range(3)] for i in range(3)]
        rs = _matmul(rot, s)
        cov = _matmul(rs, _transpose(rs))
        pc = [sum(rv[i][k] * m[k] for k in range(3)) + tv[i] for i in range(3)]
        if pc[2] < near:
            continue
        def lim(c, f, size):
            return (-c / f - 0.3 * size / (2 * f), (size - c) / f + 0.3 * size / (2 * f))
        lo, hi = lim(cx, fx, width)
        tx = pc[2] * min(hi, max(lo, pc[0] / pc[2]))
        lo, hi = lim(cy, fy, height)
        ty = pc[2] * min(hi, max(lo, pc[1] / pc[2]))
        jac = [[fx / pc[2], 0.0, -fx * tx / pc[2] ** 2], [0.0, fy / pc[2], -fy * ty / pc[2] ** 2]]
        t = _matmul(jac, rv)
        cov2 = _matmul(_matmul(t, cov), _transpose(t))
        det_raw = cov2[0][0] * cov2[1][1] - cov2[0][1] * cov2[1][0]
        a, b, c = cov2[0][0] + 0.3, cov2[0][1], cov2[1][1] + 0.3
        det = a * c - b * b
        if not det > 0:
            continue
        o = 1 / (1 + math.exp(-float(logits[g])))
        if antialiased:
            o *= math.sqrt(max(0.0, det_raw / det))
        d = [m[i] - centre[i] for i in range(3)]
        dn = math.sqrt(sum(v * v for v in d))
        colour = ref.eval_sh(np.asarray(sh[g:g + 1], np.float64), np.array([d]) / dn, ref.sh_degree_of(sh))[0]
        colour = [max(v + 0.5, 0.0) for v in colour]
        splats.append((pc[2], g, fx * pc[0] / pc[2] + cx, fy * pc[1] / pc[2] + cy,
                       c / det, -b / det, a / det, o, colour))
    splats.sort(key=lambda item: (np.float32(item[0]), item[1]))  # float32 depth key, then index
    rgb = np.zeros((height, width, 3))
    alpha = np.zeros((height, width))
    depth = np.zeros((height, width))
    for j in range(height):
        for i in range(width):
            T, col, dsum, wsum = 1.0, [0.0, 0.0, 0.0], 0.0, 0.0
            mesh_done = mesh_rgba is None

            def add_mesh():
                nonlocal T, dsum, wsum
                ma, md = float(mesh_rgba[j, i, 3]), float(mesh_depth[j, i])
                for k in range(3):
                    col[k] += T * float(mesh_rgba[j, i, k])
                if ma > 0 and math.isfinite(md):
                    dsum += T * ma * md
                    wsum += T * ma
                T *= 1 - ma

            for z, _, mx, my, ca, cb, cc, o, colour in splats:
                if not mesh_done and np.float32(z) >= mesh_depth[j, i]:
                    add_mesh()
                    mesh_done = True
                dx, dy = mx - (i + 0.5), my - (j + 0.5)
                power = -0.5 * (ca * dx * dx + cc * dy * dy) - cb * dx * dy
                if power > 0:
                    continue
                a = min(0.99, o * math.exp(power))
                if a < 1 / 255:
                    continue
                test_t = T * (1 - a)
                if test_t < 1e-4:
                    break
                for k in range(3):
                    col[k] += colour[k] * a * T
                dsum += z * a * T
                wsum += a * T
                T = test_t
            if not mesh_done:
                add_mesh()
            if background is not None:
                for k in range(3):
                    col[k] += T * float(background[k])
            rgb[j, i] = col
            alpha[j, i] = 1 - T
            depth[j, i] = dsum / wsum if wsum > 0 else math.inf
    return {"rgb": rgb, "alpha": alpha, "depth": depth}


@pytest.mark.parametrize("degree", [0, 3])
@pytest.mark.parametrize("antialiased", [False, True])
@pytest.mark.parametrize("mesh", [False, True])
def test_vectorised_equals_pure_python_loop(rng, degree, antialiased, mesh):
    # 4 Gaussians near the view centre, sized to overlap at 8x6, plus one random-scene camera.
    # Same float64 arithmetic in a different shape: equal to rounding (rtol 1e-12).
    width, height = 8, 6
    cam = random_camera(rng, width, height, distance=3.0)
    g = random_gaussians(rng, 4, degree, radius=0.4, stray=0.0)
    g.log_scales[:] = rng.uniform(np.log(0.05), np.log(0.4), size=(4, 3))
    g.opacity_logits[:] = rng.normal(1.0, 1.5, size=4)
    options = dict(antialiased=antialiased, background=rng.random(3))
    if mesh:
        options["mesh_rgba"], options["mesh_depth"] = random_mesh_layer(rng, width, height, depth_range=(2.5, 3.5))
    want = render_loop(*ref.gaussian_args(g), *ref.camera_args(cam), **options)
    got = ref.render_scene(g, cam, **options)
    assert got["alpha"].max() > 0.05  # the scene is not empty
    for key in ("rgb", "alpha"):
        np.testing.assert_allclose(got[key], want[key], rtol=1e-12, atol=1e-14)
    np.testing.assert_array_equal(np.isinf(got["depth"]), np.isinf(want["depth"]))
    finite = np.isfinite(want["depth"])
    np.testing.assert_allclose(got["depth"][finite], want["depth"][finite], rtol=1e-12)


def test_projection_matches_loop_guard_band_and_culling():
    # A Gaussian far to the side (x/z = 5, so the clamp in J is active), one behind the near
    # plane, one exactly at it: compare the vectorised projection with the scalar formulas.
    means = np.float32([[10, 1, 2], [0, 0, 0.005], [0, 0, 0.125], [0.2, -0.3, 3]])
    n = len(means)
    args = (means, np.float32([[-1, -2, -0.5]] * n), np.float32([[0.9, 0.2, -0.3, 0.1]] * n),
            np.zeros(n, np.float32), np.zeros((n, 1, 3), np.float32))
    cam = (np.eye(4), 30.0, 32.0, 20.0, 14.0, 40, 30)
    p = ref.project(*args, *cam, near=0.125)
    np.testing.assert_array_equal(p["valid"], [True, False, True, True])
    # The clamped J for the first: x/z clamped to (W - cx)/fx + 0.3 W / (2 fx).
    lim = (40 - 20) / 30 + 0.3 * 40 / 60
    z = 2.0
    rot = ref.quat_to_rotmat(args[2][:1])[0]
    cov = rot @ np.diag(np.exp(2 * args[1][0].astype(np.float64))) @ rot.T
    jac = np.array([[30 / z, 0, -30 * lim / z], [0, 32 / z, -32 * 0.5 / z]])
    cov2 = jac @ cov @ jac.T + 0.3 * np.eye(2)
    inv = np.linalg.inv(cov2)
    np.testing.assert_allclose(p["conic"][0], [inv[0, 0], inv[0, 1], inv[1, 1]], rtol=1e-12)
    np.testing.assert_allclose(p["xy"][0], [30 * 5 + 20, 32 * 0.5 + 14], rtol=1e-12)
    assert (p["conic"][1] == 0).all() and p["depth"][1] == 0  # invalid rows are zero


@pytest.mark.parametrize("excess, flagged", [(1e-5, True), (-1e-5, True), (1e-2, False), (-1e-2, False)])
def test_ambiguous_marks_alpha_at_the_skip_threshold(excess, flagged):
    # One isotropic Gaussian whose alpha at pixel (3, 3) is 1/255 (1 + excess); the pixel on
    # the mean (power 0, alpha ~0.01) is never ambiguous.
    width, height, f, z = 9, 9, 10.0, 4.0
    sigma = 0.3
    var = (f * math.exp(np.float32(math.log(sigma))) / z) ** 2 + 0.3  # float32 log-scale input
    r2 = 2 * 1.0 ** 2  # pixel (3, 3) centre is (3.5, 3.5), the mean projects to (4.5, 4.5)
    o = (1 / 255) * (1 + excess) * math.exp(0.5 * r2 / var)
    args = _one((0.0, 0.0, z), math.log(sigma), math.log(o / (1 - o)), (0.0, 0.0, 0.0))
    out = ref.render(*args, *_identity_camera(width, height, f))
    assert out["ambiguous"][3, 3] == flagged
    assert not out["ambiguous"][4, 4]
    if not flagged:
        assert (out["alpha"][3, 3] > 0) == (excess > 0)
