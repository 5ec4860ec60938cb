"""Each Gaussian's deformation Jacobian J, estimated from where its neighbours went.

Inside a render the modifier stack cannot be evaluated again on offset positions (a render may
not modify the original data), so J comes from the centres alone: with rest offsets
a_j = p_j - p and deformed offsets b_j = x_j - x to the k nearest rest neighbours, weights
w_j = exp(-|a_j|^2 / max |a|^2), J is the weighted least-squares map a -> b wherever the
neighbours spread. Where they do not (the issue's row of splats: every offset along one line;
a sheet: no offset along its normal) the data says nothing about J, and a plain pseudo-inverse
would leave those directions unchanged, which is what drew the bent row as a ladder of
horizontal dashes. There J follows the rotation R the data does determine: the smallest
rotation taking the best-spread direction to where it went, completed by the second one when
there is one. In the eigenbasis (l_m, e_m) of A = sum w a a^T:

    J = sum_m (c_m B e_m / l_m + (1 - c_m) R e_m) e_m^T,   B = sum w b a^T,

c_m ramping from 0 at l_m / l_1 = `undetermined` to 1 at `determined` (variance ratios to the
widest direction), so J changes continuously as a neighbourhood flattens. Guarantees (tests):
a neighbourhood spanning 3D (every ratio above `determined`) gives exactly the linear part of
an affine deformation; a rigid motion gives exactly its rotation wherever the neighbours span a
plane or more; a row gives its stretch along itself and the smallest rotation across. The
thresholds were picked by the accuracy table of benchmarks/bench_deform.py (docs/benchmarks/
deform.md): a direction spread less than ~0.1 of the widest (variance 1e-2) is fitted from
offsets so small that the bend's curvature dominates them.

Native (`splatcore.deformation_jacobians`, native/src/deform_fit.c); the float64 NumPy twin is
tests/reference_deform.py's `jacobians`.
"""

from __future__ import annotations

import numpy as np

from .. import native

UNDETERMINED = 1e-2  # variance ratio below which a direction follows the rotation
DETERMINED = 1e-1    # ... above which it is fitted


def deformation_jacobians(rest: np.ndarray, deformed: np.ndarray, neighbours: np.ndarray, *,
                          undetermined: float = UNDETERMINED, determined: float = DETERMINED,
                          threads: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(jacobians, rotations), float64 (N, 3, 3) each: J per point (deformed offset = J rest
    offset) and its polar rotation (the rotation the SH follow; R where J is singular)."""
    rest = np.ascontiguousarray(rest, np.float32)
    deformed = np.ascontiguousarray(deformed, np.float32)
    neighbours = np.ascontiguousarray(neighbours, np.int32)
    if rest.ndim != 2 or rest.shape[1] != 3 or deformed.shape != rest.shape:
        raise ValueError(f"rest and deformed positions must both have shape (N, 3), got "
                         f"{rest.shape} and {deformed.shape}")
    if neighbours.ndim != 2 or len(neighbours) != len(rest):
        raise ValueError(f"neighbours must have shape ({len(rest)}, k), got {neighbours.shape}")
    n = len(rest)
    jacobians = np.empty((n, 3, 3), np.float64)
    rotations = np.empty((n, 3, 3), np.float64)
    native.deformation_jacobians(rest, deformed, neighbours, jacobians, rotations,
                                 undetermined=undetermined, determined=determined,
                                 threads=threads)
    return jacobians, rotations
