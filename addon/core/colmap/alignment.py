"""Aligning a COLMAP scene: similarities, the up direction, the centre and the scale.

`alignment(cameras, xyz)` gives the similarity that stands a scene upright (Blender's +Z up),
centres and sizes it; the helpers map points and cameras by any similarity.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..cameras import Camera
from .errors import ColmapError

DEFAULT_SCENE_SIZE = 4.0


# -- similarities ----------------------------------------------------------------------------

def similarity(scale: float, rotation: np.ndarray, translation) -> np.ndarray:
    """4x4 matrix of x' = scale * rotation @ x + translation."""
    m = np.eye(4)
    m[:3, :3] = scale * np.asarray(rotation, np.float64)
    m[:3, 3] = translation
    return m


def decompose_similarity(m: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """(scale, rotation, translation) of a 4x4 similarity."""
    m = np.asarray(m, np.float64)
    scale = float(np.cbrt(np.linalg.det(m[:3, :3])))
    if not scale > 0:
        raise ValueError("not a similarity: the 3x3 part must have a positive determinant")
    return scale, m[:3, :3] / scale, m[:3, 3].copy()


def transform_points(xyz: np.ndarray, sim: np.ndarray) -> np.ndarray:
    xyz = np.asarray(xyz, np.float64).reshape(-1, 3)
    return xyz @ sim[:3, :3].T + sim[:3, 3]


def transform_camera(camera: Camera, sim: np.ndarray) -> Camera:
    """The camera that sees the world mapped by `sim` as `camera` saw the original.

    With x = R^T (x' - t) / s, camera coordinates are Rc x + tc; scaled by s (which keeps the
    projection) they are (Rc R^T) x' + (s tc - Rc R^T t): a rigid world-to-camera again.
    """
    s, r, t = decompose_similarity(sim)
    rc, tc = camera.world_to_camera[:3, :3], camera.world_to_camera[:3, 3]
    w2c = np.eye(4)
    w2c[:3, :3] = rc @ r.T
    w2c[:3, 3] = s * tc - w2c[:3, :3] @ t
    return replace(camera, world_to_camera=w2c)


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector a to unit vector b."""
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    v, c = np.cross(a, b), float(a @ b)
    if c < -1 + 1e-12:  # opposite: half a turn about any axis perpendicular to a
        axis = np.cross(a, np.eye(3)[np.argmin(np.abs(a))])
        axis /= np.linalg.norm(axis)
        return 2 * np.outer(axis, axis) - np.eye(3)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1 + c)


# -- alignment -------------------------------------------------------------------------------

def camera_up_vectors(cameras: list[Camera]) -> np.ndarray:
    """(N, 3) each camera's image-up direction in the world (-y of the OpenCV camera)."""
    return np.array([-c.world_to_camera[1, :3] for c in cameras])


def _fit_plane(points: np.ndarray) -> tuple[np.ndarray, float]:
    centroid = points.mean(axis=0)
    normal = np.linalg.svd(points - centroid, full_matrices=False)[2][2]
    return normal, float(normal @ centroid)


def ground_plane(xyz: np.ndarray, *, near: np.ndarray | None = None, max_angle: float = 30.0,
                 iterations: int = 1000, seed: int = 0) -> tuple[np.ndarray, float, int] | None:
    """The plane n.x = d holding most points (RANSAC, then least squares on its inliers).

    Inliers lie within 0.3 % of the points' robust extent (the diagonal of their 5-95 %
    box): looser tolerances let a slab through a dense cloud beat a real floor. With `near`,
    only planes whose normal is within `max_angle` degrees of it (either sign) count. Returns (unit normal, d,
    inlier count) or None (fewer than 3 points). Deterministic (fixed seed).
    """
    xyz = np.asarray(xyz, np.float64)
    if len(xyz) < 3:
        return None
    rng = np.random.default_rng(seed)
    sample = xyz if len(xyz) <= 20000 else xyz[rng.choice(len(xyz), 20000, replace=False)]
    lo, hi = np.percentile(sample, [5, 95], axis=0)
    tol = 0.003 * max(float(np.linalg.norm(hi - lo)), 1e-12)
    cos_max = np.cos(np.radians(max_angle))
    # All hypotheses at once, scored in blocks (a few large products, not thousands of small
    # ones: small BLAS calls are slow when other threads keep the cores busy).
    picks = rng.integers(0, len(sample), size=(iterations, 3))
    a, b, c = sample[picks[:, 0]], sample[picks[:, 1]], sample[picks[:, 2]]
    normals = np.cross(b - a, c - a)
    lengths = np.linalg.norm(normals, axis=1)
    keep = lengths > 1e-12 * tol * tol
    normals = normals[keep] / lengths[keep, None]
    offsets = np.einsum("ij,ij->i", normals, a[keep])
    if near is not None:
        facing = np.abs(normals @ near) >= cos_max
        normals, offsets = normals[facing], offsets[facing]
    best, best_count = None, 0
    for start in range(0, len(normals), 128):
        block_n, block_d = normals[start:start + 128], offsets[start:start + 128]
        counts = np.count_nonzero(np.abs(sample @ block_n.T - block_d) < tol, axis=0)
        top = int(np.argmax(counts))
        if counts[top] > best_count:
            best, best_count = (block_n[top], float(block_d[top])), int(counts[top])
    if best is None:
        return None
    n, d = best
    for _ in range(2):  # refine on the inliers of the full set
        inliers = xyz[np.abs(xyz @ n - d) < tol]
        if len(inliers) < 3:
            break
        n2, d2 = _fit_plane(inliers)
        if n2 @ n < 0:
            n2, d2 = -n2, -d2
        n, d = n2, d2
    count = int(np.count_nonzero(np.abs(xyz @ n - d) < tol))
    return n, d, count


def estimate_up(cameras: list[Camera], xyz: np.ndarray, method: str = "auto") -> tuple[np.ndarray, dict]:
    """The world's up direction in the cameras' frame, and how it was found.

    - "cameras": the mean of the cameras' image-up vectors (what nerfstudio calls "up"). Right
      for rings of upright cameras; tilted by the pitch for a partial arc of cameras looking
      down, and wrong for photos taken sideways.
    - "auto" (default): the cameras first: when they agree on an up direction (mean up vector
      of length > 0.9) their image-right vectors are horizontal, and the up direction is the
      one most perpendicular to all of them (exact for cameras held without roll, whatever
      their pitch); when that is ill-determined (right vectors all alike), the mean up vector.
      Then the ground: the plane holding most points within 30 degrees of that direction
      (at least 5 % of the points) gives the exact vertical. When the cameras do not agree
      (sideways or rolled photos), the dominant plane of the points is the ground if it holds
      at least 20 % of them, its normal pointed towards the cameras; else the mean up vector.

    Returns (unit up vector, info) with info["method"] naming what decided.
    """
    if method not in ("auto", "cameras"):
        raise ValueError(f"up method must be 'auto' or 'cameras', got {method!r}")
    ups = camera_up_vectors(cameras)
    mean_up = ups.mean(axis=0)
    agreement = float(np.linalg.norm(mean_up))
    if agreement < 1e-9:
        mean_up, agreement = np.array([0.0, 0.0, 1.0]), 0.0
    mean_up = mean_up / max(np.linalg.norm(mean_up), 1e-300)
    info = {"mean_up_length": agreement}
    if method == "cameras":
        info["method"] = "cameras: mean image-up vector"
        return mean_up, info

    xyz = np.asarray(xyz, np.float64)
    centres = np.array([c.centre for c in cameras])
    rights = np.array([c.world_to_camera[0, :3] for c in cameras])
    sv, vt = np.linalg.svd(rights, full_matrices=False)[1:]
    up, how = mean_up, "cameras: mean image-up vector"
    if agreement > 0.9:
        if len(cameras) >= 3 and sv[2] < 0.35 * sv[1]:
            up = vt[2] if vt[2] @ mean_up > 0 else -vt[2]
            how = "cameras: perpendicular to their image-right vectors"
        plane = ground_plane(xyz, near=up, max_angle=30.0)
        min_share = 0.05
    else:
        plane = ground_plane(xyz)
        min_share = 0.20
    info["cameras_up"] = up.tolist()
    if plane is not None and plane[2] >= max(10, min_share * len(xyz)):
        n, d, count = plane
        side = np.median(centres @ n - d)
        n = n if side > 0 else -n
        info.update(ground_normal=n.tolist(), ground_inliers=count,
                    ground_offset=float(d if side > 0 else -d))
        return n, {**info, "method": f"ground plane ({count} of {len(xyz)} points); {how}"}
    return up, {**info, "method": how}


def look_at_centre(cameras: list[Camera], xyz: np.ndarray) -> np.ndarray:
    """The point the cameras look at (least squares over their optical axes); the points'
    median where the axes are near parallel or the result is behind most cameras."""
    a, b = np.zeros((3, 3)), np.zeros(3)
    for cam in cameras:
        f = cam.world_to_camera[2, :3]
        p = np.eye(3) - np.outer(f, f)
        a += p
        b += p @ cam.centre
    if len(cameras) >= 2 and np.linalg.eigvalsh(a / len(cameras))[0] > 0.05:
        target = np.linalg.solve(a, b)
        in_front = np.mean([(c.world_to_camera @ np.append(target, 1.0))[2] > 0 for c in cameras])
        if in_front > 0.5:
            return target
    if len(xyz):
        return np.median(xyz, axis=0)
    return np.mean([c.centre for c in cameras], axis=0)


def alignment(cameras: list[Camera], xyz: np.ndarray, *, up: str = "auto",
              scene_size: float = DEFAULT_SCENE_SIZE) -> tuple[np.ndarray, dict]:
    """The similarity (4x4, x' = s R x + t) that stands the scene upright and sizes it.

    - Rotation: the up direction of `estimate_up` becomes +Z; about Z, the first camera's
      view direction becomes +Y (its photo is then what Blender's front view looks at).
    - Centre: the look-at point of the cameras (`look_at_centre`) goes to x = y = 0; along Z,
      the ground plane (when one decided the up direction) goes to z = 0, else the centre.
    - Scale: the cameras' median distance from the centre becomes `scene_size`.
    """
    if not cameras:
        raise ColmapError("nothing to align: no cameras")
    xyz = np.asarray(xyz, np.float64).reshape(-1, 3)
    up_vec, info = estimate_up(cameras, xyz, up)
    rot = _rotation_between(up_vec, np.array([0.0, 0.0, 1.0]))
    forward = rot @ cameras[0].world_to_camera[2, :3]
    if np.hypot(forward[0], forward[1]) > 1e-6:
        yaw = np.arctan2(forward[0], forward[1])  # turn forward's xy onto +Y
        c, s = np.cos(yaw), np.sin(yaw)
        rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ rot
    centre = look_at_centre(cameras, xyz)
    distances = np.linalg.norm(np.array([c.centre for c in cameras]) - centre, axis=1)
    median = float(np.median(distances))
    scale = scene_size / median if median > 1e-12 else 1.0
    centre_r = rot @ centre
    z0 = centre_r[2]
    if "ground_offset" in info:
        z0 = info["ground_offset"]  # n.x = d on the ground; n becomes +Z
    translation = -scale * np.array([centre_r[0], centre_r[1], z0])
    sim = similarity(scale, rot, translation)
    info.update(up=up_vec.tolist(), centre=centre.tolist(), scale=scale)
    return sim, info
