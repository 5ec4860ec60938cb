"""Helpers for the COLMAP tests: COLMAP's own residuals (pycolmap only, nothing of ours),
re-projection through our cameras, and synthetic COLMAP workspaces with photos."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # the annotations only; imported where used
    import pycolmap


def colmap_own_residuals(model_dir: Path) -> dict[str, np.ndarray]:
    """Per image name: |COLMAP's projection of each observed 3D point - its 2D observation|,
    in COLMAP's own (possibly distorted) pixels, computed with pycolmap alone."""
    import pycolmap

    rec = pycolmap.Reconstruction(str(model_dir))
    out = {}
    for im in rec.images.values():
        if not im.has_pose:
            continue
        obs = im.get_observation_points2D()
        xyz = np.array([rec.points3D[p.point3D_id].xyz for p in obs]).reshape(-1, 3)
        xy = np.array([p.xy for p in obs]).reshape(-1, 2)
        pose = im.cam_from_world().matrix()
        uv = im.camera.img_from_cam(xyz @ pose[:, :3].T + pose[:, 3])
        out[im.name] = np.linalg.norm(uv - xy, axis=1)
    return out


def project(camera, xyz: np.ndarray) -> np.ndarray:
    """Pinhole projection with our Camera (OpenCV convention)."""
    xc = xyz @ camera.world_to_camera[:3, :3].T + camera.world_to_camera[:3, 3]
    return np.stack([camera.fx * xc[:, 0] / xc[:, 2] + camera.cx,
                     camera.fy * xc[:, 1] / xc[:, 2] + camera.cy], axis=1)


def scene_residuals(scene) -> dict[str, np.ndarray]:
    """Per image name: |our camera's projection of each observed point - the observation|."""
    out = {}
    for im in scene.images:
        rows = scene.points.positions_of(im.point3D_ids)
        assert (rows >= 0).all()
        out[im.name] = np.linalg.norm(project(im.camera, scene.points.xyz[rows]) - im.points2D, axis=1)
    return out


# -- synthetic workspaces --------------------------------------------------------------------

def texture(nx: np.ndarray, ny: np.ndarray) -> np.ndarray:
    """A smooth colour function of normalised camera coordinates (x/z, y/z), in [0.1, 0.9]."""
    return np.stack([0.5 + 0.4 * np.sin(3.0 * nx + 0.5) * np.cos(2.0 * ny),
                     0.5 + 0.4 * np.cos(2.5 * nx - 1.5 * ny),
                     0.5 + 0.4 * np.sin(4.0 * ny + 0.3)], axis=-1)


def distorted_photo(camera, width: int | None = None, height: int | None = None) -> np.ndarray:
    """Float photo (H, W, 3) of `texture` as seen through a pycolmap camera: each pixel is
    the texture at its centre's ray (`cam_from_img`); optionally at a smaller size."""
    width = width or camera.width
    height = height or camera.height
    u, v = np.meshgrid((np.arange(width) + 0.5) * camera.width / width,
                       (np.arange(height) + 0.5) * camera.height / height)
    n = camera.cam_from_img(np.stack([u.ravel(), v.ravel()], 1))
    return texture(n[:, 0], n[:, 1]).reshape(height, width, 3)


def look_at_pose(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """cam_from_world 3x4 (OpenCV) of a camera at `eye` looking at `target`."""
    eye, target, up = (np.asarray(v, np.float64) for v in (eye, target, up))
    f = target - eye
    f /= np.linalg.norm(f)
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    d = np.cross(f, r)
    rot = np.stack([r, d, f])
    return np.concatenate([rot, (-rot @ eye)[:, None]], axis=1)


def synthetic_workspace(root: Path, cameras: list[tuple[str, int, int, list[float]]],
                        images: list[tuple[str, int]], *, rng: np.random.Generator,
                        fmt: str = ".bin", photo_writer=None, n_points: int = 300,
                        roll: float = 0.0) -> "pycolmap.Reconstruction":
    """Write root/sparse/0 (`fmt`) and root/images/<name> photos for the given cameras
    ((model, width, height, params)) and images ((name with subfolders, camera index)).

    Cameras sit on a ring around the origin looking at it, Z up (rolled by `roll` radians);
    points fill a box at the origin; observations are the exact projections through the
    (distorted) cameras. `photo_writer(path, float_pixels)` writes each photo (default:
    8-bit via files.write_pixels).
    """
    import pycolmap

    from addon.core.images import files

    rec = pycolmap.Reconstruction()
    cams = []
    for k, (model, width, height, params) in enumerate(cameras, start=1):
        cam = pycolmap.Camera(camera_id=k, model=model, width=width, height=height, params=params)
        rec.add_camera_with_trivial_rig(cam)
        cams.append(cam)
    xyz = rng.uniform(-0.8, 0.8, size=(n_points, 3))
    tracks: dict[int, list[tuple[int, int]]] = {i: [] for i in range(n_points)}
    for image_id, (name, cam_index) in enumerate(images, start=1):
        angle = 2 * np.pi * image_id / len(images)
        eye = (4 * np.cos(angle), 4 * np.sin(angle), 1.5 + 0.3 * np.sin(3 * angle))
        pose = look_at_pose(eye, (0, 0, 0))
        if roll:
            c, s = np.cos(roll), np.sin(roll)
            pose = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ pose
        cam = cams[cam_index]
        xc = xyz @ pose[:, :3].T + pose[:, 3]
        uv = cam.img_from_cam(xc)
        inside = (xc[:, 2] > 0) & (uv[:, 0] > 0) & (uv[:, 0] < cam.width) & \
                 (uv[:, 1] > 0) & (uv[:, 1] < cam.height)
        keep = np.flatnonzero(inside)
        image = pycolmap.Image(name=name, keypoints=uv[keep], camera_id=cam.camera_id,
                               image_id=image_id)
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(pose))
        for idx, point in enumerate(keep):
            tracks[int(point)].append((image_id, idx))
        path = root / "images" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        pixels = distorted_photo(cam)
        if photo_writer is None:
            files.write_pixels(path, np.round(pixels * 255).astype(np.uint8))
        else:
            photo_writer(path, pixels)
    for i, elements in tracks.items():
        if len(elements) >= 2:
            track = pycolmap.Track()
            for image_id, idx in elements:
                track.add_element(image_id, idx)
            rec.add_point3D(xyz[i], track, np.array([200, 100, 50], np.uint8))
    rec.update_point_3d_errors()
    model = root / "sparse" / "0"
    model.mkdir(parents=True, exist_ok=True)
    (rec.write_binary if fmt == ".bin" else rec.write_text)(str(model))
    return rec
