"""addon.core.deform.jacobians (native/src/deform_fit.c) against its float64 twin
(tests/reference_deform.py) on random clouds and deformations, and what the fit guarantees:
the linear part of an affine map where the neighbours span 3D, a rigid motion's rotation
wherever they span a plane, a row's stretch and smallest rotation, and the analytic bend's and
twist's Jacobians to first order in the spacing.

Tolerances: the twin computes from the same float32 positions in float64, so J agrees to
float64 rounding amplified by the neighbourhood's conditioning (1e-9 relative to |J|). The
exact cases hold to the float32 rounding of the deformed positions (about 1e-7 of the offsets,
1e-5 on J after dividing by the spread)."""

from __future__ import annotations

import numpy as np
import pytest

import reference_deform
from addon.core import native
from addon.core.deform import (DETERMINED, UNDETERMINED, deformation_jacobians, neighbourhoods,
                               rest_neighbours)
from addon.core.transform import quat_to_matrix


def smooth_deformation(rng, points: np.ndarray) -> np.ndarray:
    """A random smooth non-linear deformation (affine plus sines)."""
    a = np.eye(3) + rng.normal(scale=0.3, size=(3, 3))
    k = rng.normal(scale=1.5, size=(3, 3))
    return points @ a.T + 0.3 * np.sin(points @ k.T) + rng.normal(size=3)


def row(n: int, spacing: float) -> np.ndarray:
    p = np.zeros((n, 3))
    p[:, 0] = (np.arange(n) - (n - 1) / 2) * spacing
    return p


@pytest.mark.parametrize("shape", ["cloud", "sheet", "row", "thin slab"])
def test_native_fit_is_the_reference(rng, shape):
    n = 400
    if shape == "cloud":
        rest = rng.uniform(-1, 1, (n, 3))
    elif shape == "sheet":
        rest = np.column_stack([rng.uniform(-1, 1, (n, 2)), np.zeros(n)])
    elif shape == "row":
        rest = row(n, 0.01)
    else:
        rest = np.column_stack([rng.uniform(-1, 1, (n, 2)), rng.uniform(-0.02, 0.02, n)])
    rest = (rest @ quat_to_matrix(rng.normal(size=(1, 4)))[0].T).astype(np.float32)
    moved = smooth_deformation(rng, rest.astype(np.float64)).astype(np.float32)
    nbrs = rest_neighbours(rest, int(rng.integers(3, 13)))
    lo = float(rng.choice([0.0, UNDETERMINED, 1e-3]))
    hi = float(max(lo, rng.choice([DETERMINED, 1e-2, 0.3])))
    jac, rot = deformation_jacobians(rest, moved, nbrs, undetermined=lo, determined=hi,
                                     threads=2)
    want_j, want_q = reference_deform.jacobians(rest, moved, nbrs, lo, hi)
    size = np.linalg.norm(want_j, axis=(1, 2))
    assert (np.linalg.norm(jac - want_j, axis=(1, 2)) <= 1e-9 * size).all()
    assert np.abs(rot - want_q).max() < 1e-9
    assert np.abs(rot @ np.swapaxes(rot, 1, 2) - np.eye(3)).max() < 1e-12


def test_the_rest_half_is_the_reference_spread(rng):
    """native.deform_rest, the half of the fit a deformation's frames share (`Neighbourhoods.fit`):
    each neighbour's weight, the spread's eigenvalues and its two widest directions (up to sign,
    where the eigenvalues are apart), and the ramps, against the float64 twin's; a row without
    neighbours is all zeros."""
    n = 400
    rest = rng.uniform(-1, 1, (n, 3))
    rest[: n // 4, 2] = 0.0  # a sheet beside a cloud: ramps of both kinds
    rest = rest.astype(np.float32)
    k = int(rng.integers(3, 13))
    nbrs = rest_neighbours(rest, k)
    nbrs[5] = -1
    fit = np.empty((n, native.FIT_FIELDS + k))
    native.deform_rest(rest, nbrs, fit, undetermined=UNDETERMINED, determined=DETERMINED,
                       threads=2)
    assert np.array_equal(fit[5], np.zeros(native.FIT_FIELDS + k))
    r64 = rest.astype(np.float64)
    for i in range(n):
        if i == 5:
            continue
        a = r64[nbrs[i]] - r64[i]
        d2 = (a * a).sum(axis=1)
        w = np.exp(-d2 / d2.max())
        values, vectors = np.linalg.eigh((w[:, None] * a).T @ a)
        lam = values[::-1]
        assert np.allclose(fit[i, native.FIT_FIELDS:], w, rtol=1e-14, atol=0), i
        assert np.allclose(fit[i, 6:9], lam, rtol=0, atol=1e-12 * lam[0]), i
        for m, column in ((0, 0), (1, 3)):
            gap = min(abs(lam[m] - lam[m + 1]), abs(lam[m] - lam[m - 1]) if m else np.inf)
            if gap > 1e-3 * lam[0]:
                assert abs(fit[i, column:column + 3] @ vectors[:, 2 - m]) > 1 - 1e-9, (i, m)
        for m in (1, 2):
            want = reference_deform.ramp(lam[m] / lam[0], UNDETERMINED, DETERMINED)
            assert abs(fit[i, 8 + m] - want) < 1e-9, (i, m)
    hoods = neighbourhoods(rest, k)  # the layout's own: the same halves, by row
    by_row = np.empty_like(fit)
    native.deform_rest(hoods.rest, hoods.neighbours, by_row, undetermined=UNDETERMINED,
                       determined=DETERMINED, threads=1)
    assert np.array_equal(hoods.fit, by_row)
    with pytest.raises(ValueError, match=r"out_fit must have shape \(N, 11 \+ k\)"):
        native.deform_rest(rest, nbrs, fit[:, 1:].copy(), undetermined=UNDETERMINED,
                           determined=DETERMINED, threads=1)


def test_affine_map_is_exact_where_the_neighbours_span_3d(rng):
    # a dyadic lattice and a dyadic matrix: the deformed positions are exact in float32
    rest = np.stack(np.meshgrid(*[np.arange(-4, 5)] * 3, indexing="ij"), -1).reshape(-1, 3) * 0.25
    a = rng.integers(-8, 9, size=(3, 3)) / 8.0 + 2 * np.eye(3)
    moved = rest @ a.T + rng.integers(-8, 9, size=3) / 4.0
    jac, _ = deformation_jacobians(rest.astype(np.float32), moved.astype(np.float32),
                                   rest_neighbours(rest.astype(np.float32), 26))
    assert np.abs(jac - a).max() < 1e-12


@pytest.mark.parametrize("shape", ["cloud", "sheet"])
def test_rigid_motion_gives_its_rotation(rng, shape):
    n = 500
    rest = rng.uniform(-1, 1, (n, 3))
    if shape == "sheet":
        rest[:, 2] = 0.0
    r = quat_to_matrix(rng.normal(size=(1, 4)))[0]
    moved = rest @ r.T + rng.normal(size=3)
    nbrs = rest_neighbours(rest.astype(np.float32))
    jac, rot = deformation_jacobians(rest.astype(np.float32), moved.astype(np.float32), nbrs)
    # exact wherever the second direction is determined; the others are a row's answer
    planar = reference_deform.spread_ratios(rest, nbrs)[:, 0] >= DETERMINED
    assert planar.mean() > 0.8
    assert np.abs(jac[planar] - r).max() < 2e-5
    assert np.abs(rot[planar] - r).max() < 2e-5


def test_a_row_stretches_along_itself_and_turns_by_the_smallest_rotation():
    rest = row(41, 0.05)
    stretch, angle = 1.5, 0.7
    r = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    moved = rest @ (r @ np.diag([stretch, 1, 1])).T
    jac, rot = deformation_jacobians(rest.astype(np.float32), moved.astype(np.float32),
                                     rest_neighbours(rest.astype(np.float32), 4))
    assert np.abs(jac - r @ np.diag([stretch, 1, 1])).max() < 1e-5
    assert np.abs(rot - r).max() < 1e-5


def test_no_neighbours_or_one_point_is_the_identity(rng):
    rest = rng.normal(size=(5, 3)).astype(np.float32)
    jac, rot = deformation_jacobians(rest, rest + 1, np.full((5, 4), -1, np.int32))
    assert np.array_equal(jac, np.tile(np.eye(3), (5, 1, 1)))
    assert np.array_equal(rot, jac)


@pytest.mark.parametrize("field", ["bend", "twist"])
def test_analytic_jacobians_to_first_order_in_the_spacing(rng, field):
    """On a jittered lattice, the estimate's error against the analytic J shrinks in
    proportion to the spacing (a least-squares fit of a smooth map is first-order accurate)."""
    errors = []
    for spacing in (0.08, 0.04, 0.02):
        axis = np.arange(-0.3, 0.3 + 1e-9, spacing)
        rest = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
        rest = rest + rng.uniform(-0.2, 0.2, rest.shape) * spacing
        moved, want = (reference_deform.bend(rest, 0.5) if field == "bend"
                       else reference_deform.twist(rest, 2.0))
        jac, _ = deformation_jacobians(rest.astype(np.float32), moved.astype(np.float32),
                                       rest_neighbours(rest.astype(np.float32)))
        errors.append(np.median(np.linalg.norm(jac - want, axis=(1, 2))))
    assert errors[0] < 0.1
    assert errors[1] < 0.65 * errors[0] and errors[2] < 0.65 * errors[1], errors


def test_bad_input_is_a_clear_error(rng):
    rest = rng.normal(size=(6, 3)).astype(np.float32)
    nbrs = rest_neighbours(rest, 3)
    with pytest.raises(ValueError, match="shape"):
        deformation_jacobians(rest, rest[:5], nbrs)
    with pytest.raises(ValueError, match="shape"):
        deformation_jacobians(rest, rest, nbrs[:4])
    bad = nbrs.copy()
    bad[2, 1] = 6
    with pytest.raises(ValueError, match="neighbours"):
        deformation_jacobians(rest, rest, bad)
    with pytest.raises(ValueError, match="undetermined"):
        deformation_jacobians(rest, rest, nbrs, undetermined=0.5, determined=0.1)
    moved = rest.copy()
    moved[0, 0] = np.inf
    with pytest.raises(ValueError, match="non-finite"):
        deformation_jacobians(rest, moved, nbrs)
