"""The empty space around the training cameras, where no Gaussian belongs.

A camera stands in air. Around each training camera's centre, a ball reaching `fraction` of the
way to the nearest sparse point (in any direction) is taken as empty: the reconstruction found
no surface nearer, and the camera, and whoever held it, was there. A Gaussian inside is a
floater that only cameras far away see, painting their background: on the demo scene, splats
painting the sky for the cameras across the ring gathered right in front of the held-out
cameras between two training ones, a haze over those views alone
(docs/benchmarks/reconstruction.md). The nearest sparse point bounds each ball, so no surface
the reconstruction found is inside one."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..cameras import Camera

CHUNK = 8192  # Gaussians per block of distances (x the camera count x 8 bytes)


@dataclass(frozen=True)
class FreeSpace:
    centres: np.ndarray  # (C, 3) float64, the training cameras' centres
    radii: np.ndarray    # (C,) float64

    @classmethod
    def around(cls, cameras: list[Camera], points: np.ndarray, fraction: float) -> FreeSpace | None:
        """The balls around `cameras` given the sparse `points` (N, 3); None when `fraction`
        is 0 or there are no points."""
        points = np.asarray(points, np.float64).reshape(-1, 3)
        if fraction <= 0 or not len(points) or not cameras:
            return None
        centres = np.array([c.centre for c in cameras], np.float64)
        nearest = np.array([_nearest_distance(points, centre) for centre in centres])
        return cls(centres, fraction * nearest)

    def contains(self, means: np.ndarray) -> np.ndarray:
        """(N,) bool: which of `means` (N, 3) lie inside a camera's ball."""
        means = np.asarray(means)
        inside = np.zeros(len(means), bool)
        # |m - c|^2 < r^2  <=>  |m|^2 - 2 m.c < r^2 - |c|^2
        bound = self.radii ** 2 - (self.centres ** 2).sum(1)
        for start in range(0, len(means), CHUNK):
            block = means[start:start + CHUNK].astype(np.float64)
            d2 = (block ** 2).sum(1)[:, None] - 2.0 * block @ self.centres.T
            inside[start:start + CHUNK] = (d2 < bound).any(1)
        return inside


def _nearest_distance(points: np.ndarray, centre: np.ndarray) -> float:
    return float(np.sqrt(((points - centre) ** 2).sum(1).min()))
