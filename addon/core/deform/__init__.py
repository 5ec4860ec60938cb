"""Gaussians that follow a deformation: shapes and view-dependent colour, not only centres.

A deform stack (armature, lattice, simple deform, shape keys, geometry nodes that keep the
points...) moves each Gaussian's centre; what it does to the space around the centre is its
Jacobian J there. This package estimates J from the centres alone and applies it:

    neighbours.py   each centre's k nearest neighbours in the rest positions (a k-d tree,
                    native), cached while the rest positions stay the same (`RestNeighbours`)
    jacobians.py    J per Gaussian: weighted least squares of rest offsets to deformed offsets
                    over those neighbours, directions they do not span (a row's sides, a
                    sheet's normal) following the rotation the data determines; and J's polar
                    rotation
    apply.py        the deformed Gaussians: centres as deformed, covariance J Sigma J^T, SH
                    bands 1-3 rotated by J's polar rotation (as `core.transform` does for one
                    object matrix)

`deform(gaussians, rest, neighbours)` does both steps for Gaussians whose `means` are already
the deformed centres (what a deformed mesh's evaluated vertices are).
"""

from __future__ import annotations

import numpy as np

from ..gaussians import Gaussians
from .apply import deform_gaussians
from .jacobians import DETERMINED, UNDETERMINED, deformation_jacobians
from .neighbours import NEIGHBOURS, RestNeighbours, rest_neighbours

__all__ = ["DETERMINED", "NEIGHBOURS", "UNDETERMINED", "RestNeighbours", "deform",
           "deform_gaussians", "deformation_jacobians", "rest_neighbours"]


def deform(gaussians: Gaussians, rest: np.ndarray, neighbours: np.ndarray, *,
           threads: int = 0) -> Gaussians:
    """`gaussians` (centres deformed, everything else as stored at rest) with each shape and
    SH turned by the deformation's Jacobian at its centre, estimated from `rest` (N, 3), the
    centres before the deformation, and `neighbours` (`rest_neighbours(rest)`)."""
    jacobians, rotations = deformation_jacobians(rest, gaussians.means, neighbours,
                                                 threads=threads)
    return deform_gaussians(gaussians, jacobians, rotations, threads=threads)
