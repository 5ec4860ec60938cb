"""Each rest centre's k nearest neighbours (native: `splatcore.neighbours`, a k-d tree; the
float64 brute-force twin is in tests/reference_deform.py), laid out in a spatial order with the
rest half of each one's fit (`Neighbourhoods`), and a cache of them.

The neighbourhoods are taken in the rest positions, not the deformed ones, so that a Gaussian
keeps the same neighbours however the stack bends it (two sides of a fold pressed together do
not become neighbours), and so they are computed once per rest shape, not once per frame.

The fit reads each Gaussian's neighbours' positions every frame; in the Gaussians' own order
(a capture's, a random cloud's) those are scattered over memory, a cache miss each. In a
Z-order (Morton) of the rest positions neighbours lie a few rows apart, and walking the rows in
that order reads each position for many rows in a row, so `Neighbourhoods` holds the rows of
that order: the rest positions in it, each row's neighbours as rows, the Gaussian in each row
(`native.deform_frame` permutes a frame's deformed positions into it and walks it).

Half of each frame's fit depends on the rest positions alone (the neighbours' weights, the
directions they spread in and how far, hence which directions are fitted: `jacobians.py`), so
`Neighbourhoods` holds that half too (`native.deform_rest`, 8 * (11 + k) bytes a row: 152 MB per
million Gaussians at k = 8) and a frame computes only what the deformed positions change."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import native
from .jacobians import DETERMINED, UNDETERMINED

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


_MORTON_BITS = 10  # per axis: a 1024^3 grid over the bounding box


def _spread(v: np.ndarray) -> np.ndarray:
    """The low 10 bits of each of `v` (uint64) spread to every third bit."""
    v = v & 0x3FF
    v = (v | (v << 16)) & 0x030000FF
    v = (v | (v << 8)) & 0x0300F00F
    v = (v | (v << 4)) & 0x030C30C3
    return (v | (v << 2)) & 0x09249249


def spatial_order(points: np.ndarray) -> np.ndarray:
    """(N,) int32: the indices of `points` (N, 3) in Z-order (Morton codes of a 1024^3 grid
    over their bounding box; ties in index order)."""
    points = np.asarray(points, np.float64)
    if len(points) == 0:
        return np.zeros(0, np.int32)
    low = points.min(axis=0)
    extent = max(float((points.max(axis=0) - low).max()), 1e-30)
    cells = np.clip((points - low) * ((1 << _MORTON_BITS) / extent), 0,
                    (1 << _MORTON_BITS) - 1).astype(np.uint64)
    codes = _spread(cells[:, 0]) | (_spread(cells[:, 1]) << 1) | (_spread(cells[:, 2]) << 2)
    return np.argsort(codes, kind="stable").astype(np.int32)


@dataclass(frozen=True)
class Neighbourhoods:
    """Rest positions and neighbour lists in the rows of a spatial order (see the module's
    docstring), by row: `rest` (N, 3) float32, `neighbours` (N, k) int32 (rows; -1 none),
    `order` (N,) int32 the Gaussian in each row, `fit` (N, native.FIT_FIELDS + k) float64 the
    rest half of each row's fit (`native.deform_rest`, with the default thresholds)."""

    rest: np.ndarray
    neighbours: np.ndarray
    order: np.ndarray
    fit: np.ndarray

    def __len__(self) -> int:
        return len(self.order)

    def lists(self) -> np.ndarray:
        """The neighbour lists by Gaussian (as `rest_neighbours` gives them)."""
        by_gaussian = np.empty_like(self.neighbours)
        by_gaussian[self.order] = np.where(self.neighbours < 0, -1,
                                           self.order[np.maximum(self.neighbours, 0)])
        return by_gaussian


def neighbourhoods(rest: np.ndarray, k: int = NEIGHBOURS, *, threads: int = 0,
                   neighbours: np.ndarray | None = None) -> Neighbourhoods:
    """`rest` (N, 3) and its k nearest neighbours (`rest_neighbours`, or `neighbours` as it
    gives them) laid out in the rows of its spatial order, with the rest half of the fit."""
    points = np.ascontiguousarray(rest, np.float32)
    lists = rest_neighbours(points, k, threads=threads) if neighbours is None else \
        np.ascontiguousarray(neighbours, np.int32)
    if lists.shape[0] != len(points):
        raise ValueError(f"neighbours must have one row per point ({len(points)}), got "
                         f"{lists.shape}")
    order = spatial_order(points)
    slots = np.empty_like(order)
    slots[order] = np.arange(len(order), dtype=np.int32)
    by_row = lists[order]
    rows = np.where(by_row < 0, -1, slots[np.maximum(by_row, 0)]).astype(np.int32)
    rest_rows = np.ascontiguousarray(points[order])
    fit = np.empty((len(rows), native.FIT_FIELDS + rows.shape[1]), np.float64)
    native.deform_rest(rest_rows, rows, fit, undetermined=UNDETERMINED, determined=DETERMINED,
                       threads=threads)
    return Neighbourhoods(rest_rows, rows, order, fit)


class RestNeighbours:
    """`Neighbourhoods` by owner (any hashable: an object's identity), kept while the rest
    positions it was asked with hold the same bytes (`native.checksum`)."""

    def __init__(self) -> None:
        self._entries: dict[object, tuple[tuple, Neighbourhoods]] = {}

    def get(self, owner: object, rest: np.ndarray, k: int = NEIGHBOURS) -> Neighbourhoods:
        points = np.ascontiguousarray(rest, np.float32)
        key = (points.shape, k, native.checksum(points))
        entry = self._entries.get(owner)
        if entry is None or entry[0] != key:
            entry = (key, neighbourhoods(points, k))
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
