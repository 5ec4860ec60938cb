"""addon.core.transform (Gaussians under a 4x4 transform, SH rotation) and addon.core.cleanup,
without Blender.

Tolerances: the SH check evaluates float32 coefficients rotated by a float32 GEMM, so colours
agree to a few float32 ulps of the coefficients' size (1e-5 absolute for coefficients of order
1). Covariances are compared relative to their largest entry (1e-5: float32 storage of
quaternions and log-scales). Renders of a transformed scene seen by the transformed camera agree
to float rounding (RENDER_ATOL in checks.py, measured worst about 2e-5), except where a threshold of the
algorithm (1/255 alpha skip, 1e-4 transmittance stop, depth order of near-equal depths) flips
under rounding: at most 0.5 % of the pixels, each bounded by RENDER_FLIP_ATOL.
"""

from __future__ import annotations

import numpy as np
import pytest

from addon.core.cameras import Camera
from addon.core.cleanup import auto_radius, floater_masks, neighbour_counts
from addon.core.gaussians import Gaussians
from addon.core.render.renderer import render
from addon.core.transform import (covariances, matrix_to_quat, polar_decomposition, quat_to_matrix,
                                  rotate_sh, sh_rotation_matrices, similarity_parts,
                                  transform_gaussians)
from reference import eval_sh
from checks import compare_renders
from scenes import random_camera, random_gaussians



def random_rotation(rng) -> np.ndarray:
    return quat_to_matrix(rng.normal(size=(1, 4)))[0]


def similarity(rng, scale=None) -> np.ndarray:
    m = np.eye(4)
    s = float(np.exp(rng.uniform(np.log(0.2), np.log(5.0)))) if scale is None else scale
    m[:3, :3] = s * random_rotation(rng)
    m[:3, 3] = rng.normal(scale=3.0, size=3)
    return m


def unit_dirs(rng, n) -> np.ndarray:
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


@pytest.mark.parametrize("degree", [1, 2, 3])
@pytest.mark.parametrize("mirror", [False, True])
def test_rotated_sh_shows_the_same_colour_along_the_rotated_direction(rng, degree, mirror):
    q = random_rotation(rng) * (-1.0 if mirror else 1.0)
    sh = rng.normal(scale=0.5, size=(400, (degree + 1) ** 2, 3)).astype(np.float32)
    d = unit_dirs(rng, 400)
    rotated = rotate_sh(sh, q)
    want = eval_sh(sh, d, degree)
    got = eval_sh(rotated, d @ q.T, degree)  # rows: (Q d)^T
    assert np.abs(got - want).max() <= 1e-5
    assert np.array_equal(rotated[:, 0], sh[:, 0]), "band 0 must be copied bit for bit"


def test_sh_rotation_matrices_are_a_representation(rng):
    a, b = random_rotation(rng), random_rotation(rng)
    da, db, dab = sh_rotation_matrices(a), sh_rotation_matrices(b), sh_rotation_matrices(a @ b)
    for band in (1, 2, 3):
        assert np.allclose(da[band] @ da[band].T, np.eye(2 * band + 1), atol=1e-12)
        assert np.allclose(da[band] @ db[band], dab[band], atol=1e-12)
    identity = sh_rotation_matrices(np.eye(3))
    for band in (1, 2, 3):
        assert np.allclose(identity[band], np.eye(2 * band + 1), atol=1e-12)
    # band 1 is the vector (-y, z, -x): its matrix is R conjugated by that permutation with signs
    p = np.array([[0, -1, 0], [0, 0, 1], [-1, 0, 0]], float)
    assert np.allclose(da[1], p @ a @ p.T, atol=1e-12)


def test_sh_rotation_refuses_non_orthogonal():
    with pytest.raises(ValueError, match="orthogonal"):
        sh_rotation_matrices(np.diag([1.0, 2.0, 1.0]))


def test_quaternion_matrix_round_trip(rng):
    r = quat_to_matrix(rng.normal(size=(2000, 4)))
    assert np.abs(quat_to_matrix(matrix_to_quat(r)) - r).max() < 1e-12
    # the awkward ones: 180 degree turns about each axis
    flips = np.array([np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1])])
    assert np.abs(quat_to_matrix(matrix_to_quat(flips)) - flips).max() < 1e-12


def _assert_transformed(g: Gaussians, out: Gaussians, m: np.ndarray) -> None:
    a, t = m[:3, :3], m[:3, 3]
    means = g.means.astype(np.float64) @ a.T + t
    assert np.abs(out.means - means).max() <= 1e-6 * (1 + np.abs(means).max())
    want = a @ covariances(g) @ a.T
    scale = np.abs(want).max(axis=(1, 2), keepdims=True)
    assert (np.abs(covariances(out) - want) / scale).max() <= 1e-5
    assert np.array_equal(out.opacity_logits, g.opacity_logits)


@pytest.mark.parametrize("degree", [0, 3])
def test_similarity_transform(rng, degree):
    g = random_gaussians(rng, 300, degree)
    m = similarity(rng)
    out = transform_gaussians(g, m)
    _assert_transformed(g, out, m)
    k, q = similarity_parts(m)
    assert np.allclose(out.log_scales, g.log_scales + np.log(k), atol=1e-5)
    if degree:
        d = unit_dirs(rng, len(g))
        assert np.abs(eval_sh(out.sh, d @ q.T, degree) - eval_sh(g.sh, d, degree)).max() <= 1e-5


@pytest.mark.parametrize("kind", ["non-uniform", "sheared", "mirrored", "flat"])
def test_general_linear_transform_is_exact_for_the_shape(rng, kind):
    g = random_gaussians(rng, 300, 3)
    m = np.eye(4)
    r1, r2 = random_rotation(rng), random_rotation(rng)
    m[:3, 3] = rng.normal(size=3)
    if kind == "non-uniform":
        m[:3, :3] = r1 @ np.diag([0.5, 1.0, 3.0])
    elif kind == "sheared":
        m[:3, :3] = r1 @ np.diag([0.5, 1.0, 3.0]) @ r2
    elif kind == "mirrored":
        m[:3, :3] = r1 @ np.diag([-2.0, 2.0, 2.0])
    else:  # one axis scaled to nothing: shapes flatten, stay finite
        m[:3, :3] = r1 @ np.diag([1.0, 1.0, 0.0])
    out = transform_gaussians(g, m)
    assert out.non_finite() is None
    if kind == "flat":
        assert np.abs(out.means @ r1[:, 2] - m[:3, 3] @ r1[:, 2]).max() < 1e-5
        return
    _assert_transformed(g, out, m)
    q, _ = polar_decomposition(m[:3, :3])
    d = unit_dirs(rng, len(g))
    assert np.abs(eval_sh(out.sh, d @ q.T, 3) - eval_sh(g.sh, d, 3)).max() <= 1e-5


def test_identity_translation_and_zero_quaternions(rng):
    g = random_gaussians(rng, 50, 2)
    assert transform_gaussians(g, np.eye(4)) is g
    m = np.eye(4)
    m[:3, 3] = (1.0, -2.0, 3.0)
    moved = transform_gaussians(g, m)
    assert moved.sh is g.sh and moved.quats is g.quats
    assert np.allclose(moved.means, g.means + m[:3, 3], atol=1e-6)
    zero = Gaussians(g.means[:1], g.log_scales[:1], np.zeros((1, 4)), g.opacity_logits[:1], g.sh[:1])
    m = similarity(rng, scale=2.0)
    out = transform_gaussians(zero, m)
    assert np.allclose(quat_to_matrix(out.quats)[0], m[:3, :3] / 2.0, atol=1e-6)


def test_bad_matrices(rng):
    g = random_gaussians(rng, 5, 0)
    with pytest.raises(ValueError, match="4x4"):
        transform_gaussians(g, np.eye(3))
    bad = np.eye(4)
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        transform_gaussians(g, bad)
    bad = np.eye(4)
    bad[3, 0] = 1.0
    with pytest.raises(ValueError, match="affine"):
        transform_gaussians(g, bad)


def transformed_camera(camera: Camera, m: np.ndarray) -> tuple[Camera, float]:
    """The camera moved with the scene by the similarity `m`: world_to_camera' = s W m^-1
    (rigid again once the scale s is taken out); depths scale by s."""
    s = float(np.cbrt(np.linalg.det(m[:3, :3])))
    w2c = camera.world_to_camera @ np.linalg.inv(m)
    w2c[:3, :] *= s
    return Camera(w2c, camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height), s


@pytest.mark.parametrize("antialiased", [False, True])
def test_render_invariance_under_similarity(rng, antialiased, record_property):
    g = random_gaussians(rng, 400, 3)
    camera = random_camera(rng, 80, 60)
    m = similarity(rng)
    moved_camera, s = transformed_camera(camera, m)
    a = render(g, camera, antialiased=antialiased, threads=1)
    b = render(transform_gaussians(g, m), moved_camera, antialiased=antialiased, near=0.01 * s,
               threads=1)
    errors = compare_renders(a, b, depth_scale=s)
    record_property("invariance_errors", errors)
    print("invariance errors", errors)
    assert errors["depth_rel"] <= 1e-5


# ---------------------------------------------------------------------------------- cleanup

def brute_neighbour_counts(points: np.ndarray, radius: float) -> np.ndarray:
    cells = np.floor((points - points.min(axis=0)) / radius).astype(np.int64)
    near = np.all(np.abs(cells[:, None, :] - cells[None, :, :]) <= 1, axis=2)
    return near.sum(axis=1) - 1


def test_neighbour_counts_match_brute_force(rng):
    points = rng.normal(size=(600, 3)) * rng.uniform(0.2, 2.0)
    radius = float(rng.uniform(0.05, 0.5))
    counts = neighbour_counts(points, radius)
    assert np.array_equal(counts, brute_neighbour_counts(points, radius))
    within = (np.linalg.norm(points[:, None] - points[None], axis=2) <= radius).sum(axis=1) - 1
    assert np.all(counts >= within), "every point within the radius must be counted"


def test_floater_masks(rng):
    # dense enough that even a corner point's block (at least one 0.2-cell of cube) holds ~24
    cluster = rng.uniform(-0.5, 0.5, size=(3000, 3))
    floaters = rng.normal(size=(10, 3)) * 20.0 + 40.0 * np.sign(rng.normal(size=(10, 3)))
    means = np.concatenate([cluster, floaters])
    n = len(means)
    log_scales = np.full((n, 3), np.log(0.01)) + rng.normal(scale=0.1, size=(n, 3))
    logits = np.full(n, 3.0)
    logits[:7] = -6.0                  # opacity 0.0025: transparent
    log_scales[10:15] = np.log(1e-5)   # tiny
    masks = floater_masks(means, log_scales, logits, min_opacity=0.05, min_size_fraction=0.05,
                          radius=0.2, min_neighbours=3)
    assert np.flatnonzero(masks.transparent).tolist() == list(range(7))
    assert np.flatnonzero(masks.tiny).tolist() == list(range(10, 15))
    assert set(np.flatnonzero(masks.isolated)) >= set(range(3000, n))
    assert not masks.isolated[:3000].any()
    counts = masks.counts()
    assert counts["total"] == int(masks.any.sum())
    off = floater_masks(means, log_scales, logits, min_opacity=None, min_size_fraction=None,
                        min_neighbours=None)
    assert not off.any.any()
    assert auto_radius(means) > 0
