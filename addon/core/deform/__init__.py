"""Gaussians that follow a deformation: shapes and view-dependent colour, not only centres.

A deform stack (armature, lattice, simple deform, shape keys, geometry nodes that keep the
points...) moves each Gaussian's centre; what it does to the space around the centre is its
Jacobian J there. This package estimates J from the centres alone and applies it:

    neighbours.py   each centre's k nearest neighbours in the rest positions (a k-d tree,
                    native), laid out in rows of a spatial order so a frame's reads of them
                    are local, with the half of the fit the rest positions alone determine
                    (`Neighbourhoods`), cached while the rest positions stay the same
                    (`RestNeighbours`)
    jacobians.py    J per Gaussian: weighted least squares of rest offsets to deformed offsets
                    over those neighbours, directions they do not span (a row's sides, a
                    sheet's normal) following the rotation the data determines; and J's polar
                    rotation
    apply.py        the deformed Gaussians: centres as deformed, covariance J Sigma J^T, SH
                    bands 1-3 rotated by J's polar rotation (as `core.transform` does for one
                    object matrix)

`deform(gaussians, neighbourhoods(rest))` does both steps for Gaussians whose `means` are
already the deformed centres (what a deformed mesh's evaluated vertices are), in one native
pass (`native.deform_frame`: per Gaussian the fit then the shape and SH, over the rows of the
rest positions' spatial order) that gives the same numbers as the two steps one after the
other.
"""

from __future__ import annotations

import numpy as np

from .. import native
from ..gaussians import Gaussians
from ..transform import affine_parts, polar_decomposition
from .apply import deform_gaussians
from .jacobians import DETERMINED, UNDETERMINED, deformation_jacobians
from .neighbours import (NEIGHBOURS, Neighbourhoods, RestNeighbours, neighbourhoods,
                         rest_neighbours, spatial_order)

__all__ = ["DETERMINED", "NEIGHBOURS", "UNDETERMINED", "Neighbourhoods", "RestNeighbours",
           "deform", "deform_gaussians", "deformation_jacobians", "neighbourhoods",
           "rest_neighbours", "spatial_order"]


def deform(gaussians: Gaussians, hoods: Neighbourhoods, *, matrix: np.ndarray | None = None,
           in_place: bool = False, threads: int = 0) -> Gaussians:
    """`gaussians` (centres deformed, everything else as stored at rest) with each shape and
    SH turned by the deformation's Jacobian at its centre, estimated from the rest centres and
    their neighbours in `hoods` (`neighbourhoods(rest)`).

    `matrix` (4x4 affine): then taken by it, as `core.transform.transform_gaussians` takes
    Gaussians (the shapes by its linear part A, the SH by A's polar rotation, the centres by
    A x + t), folded into the one pass: each SH is turned once. `in_place` writes the new
    shapes and SH over `gaussians`' own arrays (a fresh read no one else holds: no new 200 MB
    of SH to fault in per million Gaussians) and returns them in a new `Gaussians`."""
    n = len(gaussians)
    if len(hoods) != n:
        raise ValueError(f"neighbourhoods of {len(hoods)} rest centres for {n} Gaussians")
    deformed = np.ascontiguousarray(gaussians.means, np.float32)
    if deformed.shape != (n, 3):
        raise ValueError(f"need (N, 3) centres, got {deformed.shape}")
    linear = rotation = None
    means = gaussians.means
    if matrix is not None:
        linear, shift = affine_parts(matrix)
        means = (deformed.astype(np.float64) @ linear.T + shift).astype(np.float32)
        if np.array_equal(linear, np.eye(3)):
            linear = None
        else:
            rotation = np.ascontiguousarray(polar_decomposition(linear)[0])
            linear = np.ascontiguousarray(linear)
    if in_place:
        arrays = (gaussians.log_scales, gaussians.quats, gaussians.sh)
        if any(a.dtype != np.float32 or not a.flags.c_contiguous or not a.flags.writeable
               for a in arrays):
            raise ValueError("deforming in place needs writable C-contiguous float32 arrays")
        log_scales, quats, sh = arrays
    else:
        log_scales = np.empty((n, 3), np.float32)
        quats = np.empty((n, 4), np.float32)
        sh = np.empty_like(gaussians.sh)
    native.deform_frame(hoods.rest, deformed, hoods.neighbours, hoods.order, hoods.fit,
                        gaussians.log_scales, gaussians.quats, gaussians.sh, log_scales, quats, sh,
                        linear=linear, linear_rotation=rotation, threads=threads)
    return Gaussians(means, log_scales, quats, gaussians.opacity_logits, sh)
