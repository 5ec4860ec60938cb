"""The one axis change between the 3DGS `.ply` frame and the y-up frames of glTF and SPZ.

A 3DGS `.ply` (and so `Gaussians` as loaded) is in the COLMAP/OpenCV frame RDF: x right, y down,
z forward. glTF (and Niantic's SPZ) use RUB: x right, y up, z back. One maps to the other by a
half turn about x, its own inverse: y and z of positions negate, the quaternion (w, x, y, z)
becomes (w, x, -y, -z), and each SH coefficient keeps or flips its sign by the parity of its basis
function in y and z. Sign flips only: exact in float32, so a round trip is bit-exact.
"""

from __future__ import annotations

import numpy as np

from ..gaussians import Gaussians

__all__ = ["rdf_to_rub"]

_POSITION = np.array([1.0, -1.0, -1.0], np.float32)
_QUATERNION = np.array([1.0, 1.0, -1.0, -1.0], np.float32)
# Basis functions in the 3DGS order, degree 1: y, z, x; 2: xy, yz, 3z^2-1, xz, x^2-y^2;
# 3: y(3x^2-y^2), xyz, y(5z^2-1), z(5z^2-3), x(5z^2-1), z(x^2-y^2), x(x^2-3y^2).
_SH = np.array([1, -1, -1, 1, -1, 1, 1, -1, 1, -1, 1, -1, -1, 1, -1, 1], np.float32)


def rdf_to_rub(gaussians: Gaussians) -> Gaussians:
    """The Gaussians turned half a turn about x (RDF <-> RUB; the same call converts back)."""
    k = gaussians.sh.shape[1]
    return Gaussians(gaussians.means * _POSITION, gaussians.log_scales, gaussians.quats * _QUATERNION,
                     gaussians.opacity_logits, gaussians.sh * _SH[:k, None])
