"""Morton (Z-order) sorting of Gaussians by position: the order splat-transform writes SOG and
compressed PLY files in, which keeps neighbours together (smaller images, tighter chunks)."""

from __future__ import annotations

import numpy as np

__all__ = ["morton_order"]


def _spread(v: np.ndarray) -> np.ndarray:
    """10-bit integers -> the same bits at every third position of 30."""
    v = (v | (v << np.uint64(16))) & np.uint64(0x030000FF)
    v = (v | (v << np.uint64(8))) & np.uint64(0x0300F00F)
    v = (v | (v << np.uint64(4))) & np.uint64(0x030C30C3)
    return (v | (v << np.uint64(2))) & np.uint64(0x09249249)


def morton_order(means: np.ndarray) -> np.ndarray:
    """Stable order of the points along a 3D Morton curve of their bounding box, 10 bits an axis."""
    if len(means) == 0:
        return np.zeros(0, np.intp)
    m = np.asarray(means, np.float64)
    lo, hi = m.min(axis=0), m.max(axis=0)
    extent = np.where(hi > lo, hi - lo, 1.0)
    q = np.minimum((m - lo) / extent * 1024.0, 1023.0).astype(np.uint64)
    code = (_spread(q[:, 0]) << np.uint64(2)) | (_spread(q[:, 1]) << np.uint64(1)) | _spread(q[:, 2])
    return np.argsort(code, kind="stable")
