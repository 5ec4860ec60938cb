"""Each rest centre's k nearest neighbours (native: `splatcore.neighbours`, a k-d tree; the
float64 brute-force twin is in tests/reference_deform.py), and a cache of them.

The neighbourhoods are taken in the rest positions, not the deformed ones, so that a Gaussian
keeps the same neighbours however the stack bends it (two sides of a fold pressed together do
not become neighbours), and so they are computed once per rest shape, not once per frame."""

from __future__ import annotations

import numpy as np

from .. import native

NEIGHBOURS = 8  # enough for a plane's fit to be over-determined, few enough to stay local


def rest_neighbours(rest: np.ndarray, k: int = NEIGHBOURS, *, threads: int = 0) -> np.ndarray:
    """(N, k) int32: the indices of the k nearest other points of each of `rest` (N, 3),
    nearest first, ties to the lower index; -1 where fewer than k others exist."""
    points = np.ascontiguousarray(rest, np.float32)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"rest positions must have shape (N, 3), got {points.shape}")
    if not np.isfinite(points).all():
        raise ValueError("rest positions hold NaN or Inf")
    k = int(k)
    if not 1 <= k <= 64:
        raise ValueError(f"k must be in 1..64, got {k}")
    out = np.empty((len(points), k), np.int32)
    native.neighbours(points, out, threads=threads)
    return out


class RestNeighbours:
    """Neighbour lists by owner (any hashable: an object's identity), kept while the rest
    positions it was asked with hold the same bytes (`native.checksum`)."""

    def __init__(self) -> None:
        self._entries: dict[object, tuple[tuple, np.ndarray]] = {}

    def get(self, owner: object, rest: np.ndarray, k: int = NEIGHBOURS) -> np.ndarray:
        points = np.ascontiguousarray(rest, np.float32)
        key = (points.shape, k, native.checksum(points))
        entry = self._entries.get(owner)
        if entry is None or entry[0] != key:
            entry = (key, rest_neighbours(points, k))
            self._entries[owner] = entry
        return entry[1]

    def keep_only(self, owners: set) -> None:
        """Forget every owner not in `owners` (objects no longer shown)."""
        for owner in [o for o in self._entries if o not in owners]:
            del self._entries[owner]

    def clear(self) -> None:
        self._entries.clear()

    def __len__(self) -> int:
        return len(self._entries)
