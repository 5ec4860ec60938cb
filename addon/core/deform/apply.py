"""Gaussians through a linear map each: the covariance J Sigma J^T (re-decomposed into a
quaternion and log-scales, as `core.transform` does for a non-uniform object scale) and SH
bands 1-3 rotated by J's polar rotation (as `core.transform.rotate_sh` does for one rotation),
per Gaussian. Native (`splatcore.deform_shapes`, native/src/deform_apply.c) for speed: NumPy's
batched eigen-decomposition alone takes about 1 s per million Gaussians; the float64 twin is
tests/reference_deform.py's `deformed`, built on `core.transform`."""

from __future__ import annotations

import numpy as np

from .. import native
from ..gaussians import Gaussians


def deform_gaussians(gaussians: Gaussians, jacobians: np.ndarray, rotations: np.ndarray, *,
                     threads: int = 0) -> Gaussians:
    """`gaussians` with each shape mapped by its Jacobian (N, 3, 3) and its SH by its orthogonal
    rotation (N, 3, 3); centres and opacities as they are (the centres are the deformed ones
    already). Raises ValueError for non-finite parameters or a rotation that is not one."""
    n = len(gaussians)
    jacobians = np.ascontiguousarray(jacobians, np.float64)
    rotations = np.ascontiguousarray(rotations, np.float64)
    if jacobians.shape != (n, 3, 3) or rotations.shape != (n, 3, 3):
        raise ValueError(f"need a 3x3 Jacobian and rotation per Gaussian ({n}), got "
                         f"{jacobians.shape} and {rotations.shape}")
    log_scales = np.empty((n, 3), np.float32)
    quats = np.empty((n, 4), np.float32)
    sh = np.empty_like(gaussians.sh)
    native.deform_shapes(gaussians.log_scales, gaussians.quats, gaussians.sh, jacobians,
                         rotations, log_scales, quats, sh, threads=threads)
    return Gaussians(gaussians.means, log_scales, quats, gaussians.opacity_logits, sh)
