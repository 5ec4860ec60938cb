"""Find floaters: splats that are transparent, tiny or isolated. Pure numpy, vectorised.

`floater_masks(means, log_scales, opacity_logits, ...)` returns one boolean mask per reason;
the Blender "Clean up" operator removes their union, scripts can use them directly. All
measures are in the space the arrays are in (the operator passes world space).

- transparent: opacity `sigmoid(logit)` below `min_opacity`. Below 1/255 a splat never shows at
  all (the renderer skips every pixel where its alpha is below 1/255).
- tiny: the largest standard deviation `exp(max log_scale)` below `min_size_fraction` times the
  median of that size over all splats.
- isolated: fewer than `min_neighbours` other splat centres in the 3x3x3 block of cubic cells
  of side `radius` around a splat's own cell. Every centre within `radius` of a splat is
  counted (and some up to `2 sqrt(3) radius` away), so a splat with `min_neighbours` others
  within `radius` is never isolated. `radius=None` picks 2 % of the diagonal of the box that
  holds the central 98 % of the centres (per axis, the 1st to the 99th percentile).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .gaussians import sigmoid

MAX_CELLS_PER_AXIS = 1 << 20  # cell coordinates are clamped here so keys fit in int64


@dataclass
class FloaterMasks:
    transparent: np.ndarray
    tiny: np.ndarray
    isolated: np.ndarray
    radius: float  # the isolation radius used

    @property
    def any(self) -> np.ndarray:
        return self.transparent | self.tiny | self.isolated

    def counts(self) -> dict[str, int]:
        return {"transparent": int(self.transparent.sum()), "tiny": int(self.tiny.sum()),
                "isolated": int(self.isolated.sum()), "total": int(self.any.sum())}


def auto_radius(means: np.ndarray) -> float:
    """2 % of the diagonal of the box holding the central 98 % of the centres (per axis)."""
    means = np.asarray(means, np.float64)
    if len(means) == 0:
        return 1.0
    lo, hi = np.percentile(means, [1.0, 99.0], axis=0)
    diagonal = float(np.linalg.norm(hi - lo))
    return 0.02 * diagonal if diagonal > 0 else 1.0


def neighbour_counts(points: np.ndarray, radius: float) -> np.ndarray:
    """For each point, how many other points lie in the 3x3x3 block of cells (side `radius`)
    around its own cell."""
    points = np.asarray(points, np.float64)
    n = len(points)
    if n == 0:
        return np.zeros(0, np.int64)
    if not radius > 0 or not np.isfinite(radius):
        raise ValueError(f"radius must be positive and finite, got {radius}")
    cells = np.floor((points - points.min(axis=0)) / radius)
    cells = np.clip(cells, 0, MAX_CELLS_PER_AXIS).astype(np.int64) + 1  # a margin of one cell
    dims = cells.max(axis=0) + 2
    keys = (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]
    unique, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
    total = np.zeros(len(unique), np.int64)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                wanted = unique + (dx * dims[1] + dy) * dims[2] + dz
                at = np.searchsorted(unique, wanted)
                at_clipped = np.minimum(at, len(unique) - 1)
                found = (at < len(unique)) & (unique[at_clipped] == wanted)
                total += np.where(found, counts[at_clipped], 0)
    return total[inverse.reshape(-1)] - 1


def floater_masks(means: np.ndarray, log_scales: np.ndarray, opacity_logits: np.ndarray, *,
                  min_opacity: float | None = 0.01, min_size_fraction: float | None = 0.05,
                  radius: float | None = None, min_neighbours: int | None = 3) -> FloaterMasks:
    """Masks of the floaters by reason (see the module docstring); a criterion set to None is
    off (its mask is all False)."""
    n = len(means)
    none = np.zeros(n, bool)
    transparent = none.copy()
    if min_opacity is not None:
        transparent = sigmoid(opacity_logits) < min_opacity
    tiny = none.copy()
    if min_size_fraction is not None and n:
        size = np.max(np.asarray(log_scales, np.float64), axis=1)
        tiny = size < np.median(size) + np.log(min_size_fraction) if min_size_fraction > 0 else none
    isolated = none.copy()
    used_radius = float(radius) if radius else auto_radius(means)
    if min_neighbours is not None and min_neighbours > 0 and n:
        isolated = neighbour_counts(means, used_radius) < min_neighbours
    return FloaterMasks(transparent, tiny, isolated, used_radius)
