"""Quaternions as files store them: unit length, and the "smallest three" split.

Both SOG and the compressed .ply store a unit quaternion as the index of its largest |component|
(made positive: q and -q are one rotation) and the other three in index order; they differ only
in how many bits those three get.
"""

from __future__ import annotations

import numpy as np

__all__ = ["unit_quaternions", "smallest_three"]

_OTHERS = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])


def unit_quaternions(quats: np.ndarray) -> np.ndarray:
    """(N, 4) float64 of unit length; an all-zero quaternion becomes the identity (w first)."""
    q = np.asarray(quats, np.float64)
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    return np.where(norm > 0, q / np.where(norm > 0, norm, 1.0), [1.0, 0.0, 0.0, 0.0])


def smallest_three(quats: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(index of the largest |component| (the first on ties), (N, 3) the other three in order,
    in [-1/sqrt(2), 1/sqrt(2)]) of the normalised `quats`, signed so the largest is positive."""
    q = unit_quaternions(quats)
    largest = np.argmax(np.abs(q), axis=1)
    q *= np.where(q[np.arange(len(q)), largest] < 0, -1.0, 1.0)[:, None]
    return largest, np.take_along_axis(q, _OTHERS[largest], axis=1)
