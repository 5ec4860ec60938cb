"""addon.core.deform.apply (native/src/deform_apply.c) against its float64 twin
(tests/reference_deform.py's `deformed`, built on core.transform): covariances J Sigma J^T and
SH rotated, a different matrix per Gaussian, on random Gaussians and matrices (shears,
near-singular, mirrored), and what a rotation must keep: the colour seen along Q d is the one
seen along d before.

Tolerances (as tests/core/test_transform.py): covariances relative to their largest entry
1e-5 (float32 quaternions and log-scales); SH colours 1e-5 absolute for coefficients of order 1
(float32 storage); band 0 bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

import reference_deform
from addon.core.deform import (Neighbourhoods, deform, deform_gaussians, deformation_jacobians,
                              neighbourhoods, rest_neighbours)
from addon.core.gaussians import Gaussians
from addon.core.transform import covariances, quat_to_matrix, transform_gaussians
from reference import eval_sh
from scenes import random_gaussians


def random_matrices(rng, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians of every kind (rotations, shears, strong anisotropy, mirrors) and their polar
    rotations."""
    rot = quat_to_matrix(rng.normal(size=(n, 4)))
    stretch = np.exp(rng.normal(scale=0.7, size=(n, 3)))
    shear = np.eye(3) + np.triu(rng.normal(scale=0.5, size=(n, 3, 3)), 1)
    jac = rot @ (shear * stretch[:, None, :])
    jac[rng.random(n) < 0.1] *= -1.0  # mirrored
    u, _, vt = np.linalg.svd(jac)
    return jac, u @ vt


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_native_shapes_and_sh_are_the_reference(rng, degree):
    g = random_gaussians(rng, 300, degree)
    jac, rot = random_matrices(rng, len(g))
    out = deform_gaussians(g, jac, rot, threads=2)
    want = reference_deform.deformed(g, jac, rot)
    cov, cov_want = covariances(out), covariances(want)
    scale = np.abs(cov_want).max(axis=(1, 2), keepdims=True)
    assert (np.abs(cov - cov_want) / scale).max() <= 1e-5
    assert np.abs(out.sh - want.sh).max() <= 1e-5
    assert np.array_equal(out.sh[:, 0], g.sh[:, 0])
    assert out.means is g.means and out.opacity_logits is g.opacity_logits
    assert np.allclose(np.linalg.norm(out.quats, axis=1), 1.0, atol=1e-6)


def test_a_gaussian_comes_out_the_same_whatever_its_batch(rng):
    """The native shapes and SH go eight Gaussians at a time through vector lanes, the lanes the
    closed-form eigen-decomposition does not suit (here the thinnest Gaussians, flatter than
    1:30000) through the scalar code: each Gaussian's numbers are the same bit for bit in any
    order, so with any neighbours in its batch; and every one holds the float64 twin's
    tolerances."""
    g = random_gaussians(rng, 203, 3)  # not a multiple of eight: a short last batch
    log_scales = g.log_scales.copy()
    thin = rng.random(len(g)) < 0.3
    log_scales[thin, 2] -= 12.0  # variance ratio below 1e-9
    g = Gaussians(g.means, log_scales, g.quats, g.opacity_logits, g.sh)
    jac, rot = random_matrices(rng, len(g))
    out = deform_gaussians(g, jac, rot)
    want = reference_deform.deformed(g, jac, rot)
    cov, cov_want = covariances(out), covariances(want)
    scale = np.abs(cov_want).max(axis=(1, 2), keepdims=True)
    assert (np.abs(cov - cov_want) / scale).max() <= 1e-5
    assert np.abs(out.sh - want.sh).max() <= 1e-5
    for _ in range(3):
        perm = rng.permutation(len(g))
        again = deform_gaussians(g.subset(perm), jac[perm], rot[perm], threads=2)
        for name in ("log_scales", "quats", "sh"):
            assert np.array_equal(getattr(again, name), getattr(out, name)[perm]), name


def test_a_rotation_keeps_the_colour_seen_from_the_turned_direction(rng):
    g = random_gaussians(rng, 200, 3)
    rot = quat_to_matrix(rng.normal(size=(len(g), 4)))
    rot[::3] *= -1.0  # a mirror too: Q orthogonal is all the SH rotation needs
    out = deform_gaussians(g, rot, rot)
    d = rng.normal(size=(len(g), 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    turned = np.einsum("nij,nj->ni", rot, d)
    assert np.abs(eval_sh(out.sh, turned, 3) - eval_sh(g.sh, d, 3)).max() <= 1e-5


def test_flattening_keeps_log_scales_finite(rng):
    g = random_gaussians(rng, 50, 1)
    jac = np.tile(np.diag([1.0, 1.0, 0.0]), (len(g), 1, 1))
    out = deform_gaussians(g, jac, np.tile(np.eye(3), (len(g), 1, 1)))
    assert np.isfinite(out.log_scales).all()
    assert np.abs(covariances(out)[:, 2, :]).max() < 1e-10


def test_bad_matrices_are_a_clear_error(rng):
    g = random_gaussians(rng, 5, 1)
    eye = np.tile(np.eye(3), (5, 1, 1))
    with pytest.raises(ValueError, match="Jacobian and rotation per Gaussian"):
        deform_gaussians(g, eye[:4], eye)
    skewed = eye.copy()
    skewed[2, 0, 1] = 0.3
    with pytest.raises(ValueError, match="not orthogonal"):
        deform_gaussians(g, eye, skewed)
    bad = eye.copy()
    bad[1, 1, 1] = np.nan
    with pytest.raises(ValueError, match="not finite"):
        deform_gaussians(g, bad, eye)


def test_deform_follows_an_analytic_twist(rng):
    """The whole step on a dense cloud: each Gaussian's covariance is the analytic J Sigma J^T to
    within the fit's first-order error (spacing 0.02 against a twist of 2 rad per unit)."""
    axis = np.arange(-0.2, 0.2 + 1e-9, 0.02)
    rest = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    g = random_gaussians(rng, len(rest), 2)
    moved, jac = reference_deform.twist(rest, 2.0)
    g = Gaussians(moved, g.log_scales, g.quats, g.opacity_logits, g.sh)
    out = deform(g, neighbourhoods(rest))
    want = reference_deform.deformed(g, jac, np.stack([reference_deform.polar(j) for j in jac]))
    cov, cov_want = covariances(out), covariances(want)
    scale = np.abs(cov_want).max(axis=(1, 2), keepdims=True)
    assert np.median((np.abs(cov - cov_want) / scale).max(axis=(1, 2))) < 0.02
    assert np.median(np.abs(out.sh - want.sh).max(axis=(1, 2))) < 0.02


@pytest.mark.parametrize("degree", [0, 3])
def test_one_pass_is_the_two_stages_for_every_thread_count(rng, degree):
    """`deform` (native deform_frame: fit and shapes per Gaussian over the rows of a spatial
    order) gives bit for bit what the fit in the Gaussians' order then the shapes give, with 1,
    2 or 5 threads; a hidden-free random cloud under a smooth random deformation."""
    n = int(rng.integers(5000, 9000))  # more than one grain of rows per thread
    rest = rng.uniform(-1, 1, (n, 3)).astype(np.float32)
    a = np.eye(3) + rng.normal(scale=0.3, size=(3, 3))
    moved = (rest @ a.T + 0.3 * np.sin(rest @ rng.normal(scale=1.5, size=(3, 3)))) \
        .astype(np.float32)
    g = random_gaussians(rng, n, degree)
    g = Gaussians(moved, g.log_scales, g.quats, g.opacity_logits, g.sh)
    jac, rot = deformation_jacobians(rest, moved, rest_neighbours(rest))
    want = deform_gaussians(g, jac, rot)
    hoods = neighbourhoods(rest)
    for threads in (1, 2, 5):
        out = deform(g, hoods, threads=threads)
        for name in ("log_scales", "quats", "sh"):
            assert np.array_equal(getattr(out, name), getattr(want, name)), (threads, name)
        assert out.means is g.means and out.opacity_logits is g.opacity_logits
    copy = Gaussians(*(a.copy() for a in g.arrays().values()))
    out = deform(copy, hoods, in_place=True)  # over its own arrays: the same numbers
    for name in ("log_scales", "quats", "sh"):
        assert getattr(out, name) is getattr(copy, name), name
        assert np.array_equal(getattr(copy, name), getattr(want, name)), name


@pytest.mark.parametrize("kind", ["rotation", "similarity", "shear", "mirror"])
def test_an_object_matrix_folds_into_the_one_pass(rng, kind):
    """`deform(..., matrix=M)` is `transform_gaussians(deform(...), M)` (the gather's object
    matrix after the deformation), with each SH turned once: the centres bit for bit, the
    covariances and SH to float32 rounding (as test_native_shapes_and_sh_are_the_reference)."""
    n = 3000
    rest = rng.uniform(-1, 1, (n, 3)).astype(np.float32)
    moved = (rest + 0.2 * np.sin(2.0 * rest[:, [1, 2, 0]])).astype(np.float32)
    g = random_gaussians(rng, n, 3)
    g = Gaussians(moved, g.log_scales, g.quats, g.opacity_logits, g.sh)
    linear = quat_to_matrix(rng.normal(size=(1, 4)))[0]
    if kind == "similarity":
        linear = 2.5 * linear
    elif kind == "shear":
        linear = linear @ (np.eye(3) + np.triu(rng.normal(scale=0.5, size=(3, 3)), 1))
    elif kind == "mirror":
        linear = linear @ np.diag([1.0, -1.0, 1.0])
    matrix = np.eye(4)
    matrix[:3, :3], matrix[:3, 3] = linear, rng.normal(size=3)
    hoods = neighbourhoods(rest)
    out = deform(g, hoods, matrix=matrix, threads=2)
    want = transform_gaussians(deform(g, hoods), matrix)
    assert np.array_equal(out.means, want.means)
    cov, cov_want = covariances(out), covariances(want)
    scale = np.abs(cov_want).max(axis=(1, 2), keepdims=True)
    assert (np.abs(cov - cov_want) / scale).max() <= 1e-5
    assert np.abs(out.sh - want.sh).max() <= 1e-5
    with pytest.raises(ValueError, match="affine"):
        deform(g, hoods, matrix=np.ones((4, 4)))


def test_one_pass_checks_its_inputs(rng):
    rest = rng.normal(size=(50, 3)).astype(np.float32)
    g = random_gaussians(rng, 50, 1)
    hoods = neighbourhoods(rest, 4)
    with pytest.raises(ValueError, match="neighbourhoods of 50 rest centres for 49"):
        deform(g.subset(np.arange(49)), hoods)
    order = hoods.order.copy()
    order[3] = order[4]
    with pytest.raises(ValueError, match="permutation"):
        deform(g, Neighbourhoods(hoods.rest, hoods.neighbours, order, hoods.fit))
    bad = hoods.neighbours.copy()
    bad[2, 1] = 50
    with pytest.raises(ValueError, match="not a point's index"):
        deform(g, Neighbourhoods(hoods.rest, bad, hoods.order, hoods.fit))
    with pytest.raises(ValueError, match=r"fit must have shape \(N, 11 \+ k\) = \(N, 15\)"):
        deform(g, Neighbourhoods(hoods.rest, hoods.neighbours, hoods.order,
                                 np.ascontiguousarray(hoods.fit[:, :-1])))
    fit = hoods.fit.copy()
    fit[7, 3] = np.nan
    with pytest.raises(ValueError, match="fit has a non-finite value"):
        deform(g, Neighbourhoods(hoods.rest, hoods.neighbours, hoods.order, fit))


def test_float64_maps_are_checked_as_float64(rng):
    """The object matrix's parts are float64 (FINITE): checked as such. Read as float32 (a
    binding declared them finite as if float32 once), a finite double whose low half has a NaN's
    bits was refused about one run in six."""
    rest = rng.normal(size=(50, 3)).astype(np.float32)
    g = random_gaussians(rng, 50, 1)
    hoods = neighbourhoods(rest, 4)
    scale = np.frombuffer(np.array([0x3FF000007FC00000], np.uint64).tobytes(), np.float64)[0]
    assert np.isfinite(scale) and np.isnan(np.array([scale]).view(np.float32)[0])
    matrix = np.diag([scale, scale, scale, 1.0])
    out = deform(g, hoods, matrix=matrix)
    assert np.isfinite(out.log_scales).all()
    with pytest.raises(ValueError, match="non-finite"):
        deform(g, hoods, matrix=np.diag([np.inf, 1.0, 1.0, 1.0]))
