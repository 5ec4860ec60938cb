"""COLMAP cameras to pinhole: the pinhole camera pycolmap chooses for a distorted one, image
points and photo pixels mapped into it, and the undistorted model written as COLMAP binary."""

from __future__ import annotations

import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..atomic import move_files_into
from ..cameras import Camera
from .checks import inside
from .errors import ColmapError, import_pycolmap
from .scene import PINHOLE_MODELS, ColmapImage


@dataclass
class PinholeIntrinsics:
    """A COLMAP camera's pinhole replacement at COLMAP's resolution, and its source."""
    source: object  # pycolmap.Camera (distorted or not)
    model: str
    pinhole: Camera  # identity pose, COLMAP's resolution

    @property
    def distorted(self) -> bool:
        return self.model not in PINHOLE_MODELS


def pinhole_of(camera, options, where: Path | str = "COLMAP model") -> PinholeIntrinsics:
    """The pinhole replacement of a pycolmap camera; errors name `where` (the cameras file)."""
    pycolmap = import_pycolmap()
    model = camera.model.name
    if model == "SIMPLE_PINHOLE":
        f, cx, cy = camera.params
        return _intrinsics(camera, model, (f, f, cx, cy), camera.width, camera.height)
    if model == "PINHOLE":
        return _intrinsics(camera, model, camera.params, camera.width, camera.height)
    if not camera.is_perspective():
        raise ColmapError(f"{where}: camera {camera.camera_id}: the {model} model has no pinhole "
                          f"equivalent (not a perspective camera)")
    try:
        pin = pycolmap.undistort_camera(options, camera)
    except Exception as error:  # noqa: BLE001
        raise ColmapError(f"{where}: camera {camera.camera_id} ({model}): cannot undistort: {error}") from error
    try:
        return _intrinsics(camera, model, pin.params, pin.width, pin.height)
    except ValueError as error:  # e.g. distortion so strong that no pinhole camera fits
        raise ColmapError(f"{where}: camera {camera.camera_id} ({model}): no usable pinhole "
                          f"camera: {error}") from error


def _intrinsics(camera, model: str, params, width: int, height: int) -> PinholeIntrinsics:
    fx, fy, cx, cy = params
    return PinholeIntrinsics(camera, model, Camera(np.eye(4), fx, fy, cx, cy, width, height))


def scaled_size(intr: PinholeIntrinsics, sx: float, sy: float, photo: tuple[int, int] | None) -> tuple[int, int]:
    if photo is not None and not intr.distorted:
        return photo
    return max(1, round(intr.pinhole.width * sx)), max(1, round(intr.pinhole.height * sy))


def pinhole_camera(intr: PinholeIntrinsics, size: tuple[int, int], w2c: np.ndarray) -> Camera:
    """Our Camera for intrinsics scaled to `size` (the pinhole image's size)."""
    pin = intr.pinhole
    kx, ky = size[0] / pin.width, size[1] / pin.height
    return Camera(w2c, pin.fx * kx, pin.fy * ky, pin.cx * kx, pin.cy * ky, size[0], size[1])


def undistort_points(intr: PinholeIntrinsics, camera: Camera, xy: np.ndarray) -> np.ndarray:
    """Pixels of COLMAP's (distorted, full-size) camera -> pixels of `camera`."""
    if len(xy) == 0:
        return np.zeros((0, 2))
    if intr.distorted:
        normalised = intr.source.cam_from_img(np.ascontiguousarray(xy, np.float64))
    else:
        pin = intr.pinhole
        with np.errstate(over="ignore", invalid="ignore"):  # non-finite results are dropped
            normalised = np.stack([(xy[:, 0] - pin.cx) / pin.fx, (xy[:, 1] - pin.cy) / pin.fy], 1)
    return np.stack([camera.fx * normalised[:, 0] + camera.cx,
                     camera.fy * normalised[:, 1] + camera.cy], 1)


def undistortion_map(intr: PinholeIntrinsics, camera: Camera,
                     photo_size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """For each pixel centre of the pinhole `camera`: where it lies in the distorted photo of
    size `photo_size` (continuous coordinates, pixel centres at i + 0.5)."""
    u = (np.arange(camera.width) + 0.5 - camera.cx) / camera.fx
    v = (np.arange(camera.height) + 0.5 - camera.cy) / camera.fy
    uu, vv = np.meshgrid(u, v)
    rays = np.stack([uu.ravel(), vv.ravel(), np.ones(uu.size)], 1)
    xy = intr.source.img_from_cam(rays)  # COLMAP's full-size distorted pixels
    sx, sy = photo_size[0] / intr.source.width, photo_size[1] / intr.source.height
    return (xy[:, 0] * sx).reshape(uu.shape), (xy[:, 1] * sy).reshape(uu.shape)


def write_undistorted_model(rec, registered, images: list[ColmapImage],
                             intrinsics: dict[int, PinholeIntrinsics], folder: Path) -> None:
    """The model with pinhole cameras and every 2D point moved accordingly, as COLMAP binary
    in folder/sparse/0 (with folder/images, a COLMAP workspace). One rig per camera. What
    `read_colmap` dropped as non-finite is left out here too (non-finite keypoints become
    (0, 0), observed by no point)."""
    pycolmap = import_pycolmap()
    out = pycolmap.Reconstruction()
    camera_ids: dict[tuple, int] = {}
    unusable: set[tuple[int, int]] = set()  # (image id, keypoint index) of non-finite keypoints
    for im, ours in zip(registered, images):
        cam = ours.camera
        key = (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy)
        if key not in camera_ids:
            camera_ids[key] = len(camera_ids) + 1
            out.add_camera_with_trivial_rig(pycolmap.Camera(
                camera_id=camera_ids[key], model="PINHOLE", width=cam.width, height=cam.height,
                params=[cam.fx, cam.fy, cam.cx, cam.cy]))
        xy = np.array([p.xy for p in im.points2D], np.float64).reshape(-1, 2)
        moved = undistort_points(intrinsics[im.camera_id], cam, xy)
        bad = ~np.isfinite(moved).all(axis=1)
        moved[bad] = 0.0
        unusable.update((im.image_id, int(k)) for k in np.flatnonzero(bad))
        image = pycolmap.Image(name=im.name, keypoints=moved, camera_id=camera_ids[key],
                               image_id=im.image_id)
        out.add_image_with_trivial_frame(image, im.cam_from_world())
    for point in rec.points3D.values():
        elements = [e for e in point.track.elements if (e.image_id, e.point2D_idx) not in unusable]
        if elements and np.isfinite(point.xyz).all() and np.isfinite(point.error):
            out.add_point3D(point.xyz, pycolmap.Track(elements), point.color)
    out.update_point_3d_errors()
    target = inside(folder, "sparse/0", folder, "undistorted model")
    target.mkdir(parents=True, exist_ok=True)
    # pycolmap follows whatever links a (downloaded) cache folder holds: it writes into a folder
    # of our own, and the files are renamed into place (a rename replaces a link, never its target).
    fresh = Path(tempfile.mkdtemp(prefix=".model.", dir=target))
    try:
        out.write_binary(str(fresh))
        move_files_into(fresh, target)
    except Exception as error:  # noqa: BLE001
        raise ColmapError(f"{target}: cannot write the undistorted model: {error}") from error
    finally:
        shutil.rmtree(fresh, ignore_errors=True)
