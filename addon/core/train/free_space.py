"""The empty space around the training cameras, where no Gaussian belongs.

A camera stands in air. Around each training camera's centre, a ball reaching `fraction` of the
way to the nearest sparse point (in any direction) is taken as empty: the reconstruction found
no surface nearer, and the camera, and whoever held it, was there. A Gaussian inside, out of
that camera's view, is a floater that only cameras far away see, painting their background
(one in its view, close up, the camera's own loss judges): on the demo scene, splats
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
    cameras: tuple[Camera, ...]  # the training cameras (pinhole) with a ball
    centres: np.ndarray          # (C, 3) float64, their centres
    radii: np.ndarray            # (C,) float64

    @classmethod
    def around(cls, cameras: list[Camera], points: np.ndarray, fraction: float) -> FreeSpace | None:
        """The balls around the pinhole `cameras` given the sparse `points` (N, 3); None when
        `fraction` is 0 or there are no points or no such cameras."""
        points = np.asarray(points, np.float64).reshape(-1, 3)
        cameras = tuple(c for c in cameras if c.is_pinhole)
        if fraction <= 0 or not len(points) or not cameras:
            return None
        centres = np.array([c.centre for c in cameras], np.float64)
        nearest = np.array([_nearest_distance(points, centre) for centre in centres])
        return cls(cameras, centres, fraction * nearest)

    def contains(self, means: np.ndarray) -> np.ndarray:
        """(N,) bool: which of `means` (N, 3) lie inside a camera's ball and out of its view
        (what the camera sees close up, its own loss judges)."""
        means = np.asarray(means)
        inside = np.zeros(len(means), bool)
        # |m - c|^2 < r^2  <=>  |m|^2 - 2 m.c < r^2 - |c|^2
        bound = self.radii ** 2 - (self.centres ** 2).sum(1)
        for start in range(0, len(means), CHUNK):
            block = means[start:start + CHUNK].astype(np.float64)
            near = (block ** 2).sum(1)[:, None] - 2.0 * block @ self.centres.T < bound
            for index in np.flatnonzero(near.any(0)):
                rows = np.flatnonzero(near[:, index])
                inside[start + rows[~_in_view(self.cameras[index], block[rows])]] = True
        return inside


def _nearest_distance(points: np.ndarray, centre: np.ndarray) -> float:
    return float(np.sqrt(((points - centre) ** 2).sum(1).min()))


def _in_view(camera: Camera, points: np.ndarray) -> np.ndarray:
    """(N,) bool: which `points` a pinhole camera's image shows (in front, within its frame)."""
    p = np.asarray(points, np.float64) @ camera.world_to_camera[:3, :3].T \
        + camera.world_to_camera[:3, 3]
    z = p[:, 2]
    front = z > 0
    safe = np.where(front, z, 1.0)
    u = camera.fx * p[:, 0] / safe + camera.cx
    v = camera.fy * p[:, 1] / safe + camera.cy
    return front & (u >= 0) & (u <= camera.width) & (v >= 0) & (v <= camera.height)
