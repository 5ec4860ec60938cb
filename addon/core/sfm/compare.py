"""How close one model's cameras are to another's: a similarity alignment of the camera centres
(Umeyama's, via pycolmap), then per photo the rotation error in degrees and the position error
as a share of the scene size (the largest distance between two reference camera centres).
For checking a reconstruction against known cameras (renders) or a shipped model."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class PoseErrors:
    names: list[str]  # photos in both models
    rotation_deg: np.ndarray
    position: np.ndarray  # share of the scene size
    scene_size: float

    def summary(self) -> str:
        if not self.names:
            return "no photo in common"
        return (f"{len(self.names)} photos: rotation error median {np.median(self.rotation_deg):.3f}, "
                f"max {self.rotation_deg.max():.3f} deg; position error median "
                f"{100 * np.median(self.position):.3f} %, max {100 * self.position.max():.3f} % "
                f"of the scene size")


def pose_errors(pycolmap, found: dict[str, tuple[np.ndarray, np.ndarray]],
                truth: dict[str, tuple[np.ndarray, np.ndarray]]) -> PoseErrors:
    """`found`, `truth`: name -> (world_from_camera rotation 3x3, camera centre 3), both in
    OpenCV's camera axes, each in its own world frame."""
    names = sorted(set(found) & set(truth))
    centres = np.array([truth[n][1] for n in truth], np.float64)
    size = float(max(np.linalg.norm(a - b) for a in centres for b in centres)) if len(truth) else 0.0
    if len(names) < 3:
        return PoseErrors(names, np.full(len(names), np.inf), np.full(len(names), np.inf), size)
    src = np.array([found[n][1] for n in names], np.float64)
    tgt = np.array([truth[n][1] for n in names], np.float64)
    sim = pycolmap.estimate_sim3d(src, tgt)
    if sim is None:
        raise ValueError("no similarity aligns the two sets of camera centres")
    aligned = np.array([sim * p for p in src])
    rotation = np.asarray(sim.rotation.matrix())
    angles = []
    for name in names:
        relative = (rotation @ found[name][0]).T @ truth[name][0]
        cos = np.clip((np.trace(relative) - 1.0) / 2.0, -1.0, 1.0)
        angles.append(np.degrees(np.arccos(cos)))
    return PoseErrors(names, np.array(angles), np.linalg.norm(aligned - tgt, axis=1) / size, size)


def largest_step(poses: dict[str, tuple[np.ndarray, np.ndarray]]) -> float:
    """For photos taken in name order (a video's frames): the largest distance between two
    consecutive camera centres, in median distances. A smooth path stays near 1-2; a segment
    of cameras placed on the wrong side of a symmetric object shows as a jump of 10 or more."""
    from .source import natural_key

    names = sorted(poses, key=natural_key)
    centres = np.array([poses[n][1] for n in names])
    steps = np.linalg.norm(np.diff(centres, axis=0), axis=1)
    return float(steps.max() / np.median(steps)) if len(steps) else 0.0


def model_poses(model) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """name -> (world_from_camera rotation, centre) of a pycolmap Reconstruction's placed photos."""
    poses = {}
    for image in model.images.values():
        if image.has_pose:
            cam_from_world = image.cam_from_world()
            rotation = np.asarray(cam_from_world.rotation.matrix())
            poses[image.name] = (rotation.T, np.asarray(image.projection_center()))
    return poses
