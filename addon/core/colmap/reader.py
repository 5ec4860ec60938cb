"""`read_colmap`: a COLMAP model or workspace to a `ColmapScene` (see the package docstring)."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from .alignment import DEFAULT_SCENE_SIZE
from .cache import Progress, cache_key, choose_cache, write_photo_copies
from .checks import check_point_ids, check_pose, image_name, model_file
from .errors import ColmapError, import_pycolmap
from .model import find_image_dir, find_model, find_photos, folder_factor, read_reconstruction
from .scene import ColmapImage, ColmapPoints, ColmapScene
from .undistort import pinhole_camera, pinhole_of, scaled_size, undistort_points, write_undistorted_model


def read_colmap(path: str | os.PathLike, image_folder: str = "images", *,
                cache_dir: str | os.PathLike | None = None, require_photos: bool = True,
                copy_photos: bool = True, align: bool = False, up: str = "auto", scene_size: float = DEFAULT_SCENE_SIZE,
                threads: int = 0, progress: Progress | None = None) -> ColmapScene:
    """Read a COLMAP model or workspace; see the package docstring.

    image_folder: a folder name beside the model (`images`, `images_2`, ...) or an absolute
        path. require_photos: raise when none of the registered images' photos is there
        (False: cameras and points only). cache_dir: where undistorted (or turned upright)
        copies of photos go, in a subfolder named after the image folder and a key of the
        input; None: `<workspace>/splat_cache` if writable, else `user_cache_dir()`.
        copy_photos: False skips writing those copies (cameras only: the `path` of an image
        that needs one stays None).
    align, up, scene_size: see `ColmapScene.aligned`. threads: 0 uses every core.
    progress(fraction, message) is called as the work goes; it may raise to cancel.
    """
    pycolmap = import_pycolmap()
    report = progress or (lambda fraction, message: None)
    timings: dict[str, float] = {}
    start = clock = time.perf_counter()

    def lap(name: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        timings[name] = now - clock
        clock = now

    path = Path(path)
    model_dir = find_model(path)
    report(0.0, f"reading {model_dir}")
    rec = read_reconstruction(model_dir)
    images_file, points_file = model_file(model_dir, "images"), model_file(model_dir, "points3D")
    registered = [im for im in rec.images.values() if im.has_pose]
    for im in registered:
        image_name(im, images_file)  # UTF-8 and inside the image folder, before any use
    registered.sort(key=lambda im: im.name)
    if not registered:
        raise ColmapError(f"{model_dir}: the model has no registered images")
    lap("read_model")

    image_dir = find_image_dir(path, model_dir, image_folder)
    found, missing = find_photos(registered, rec, image_dir, images_file)
    if not found and require_photos:
        where = image_dir if image_dir is not None else f"{image_folder} (no such folder beside {model_dir})"
        first = registered[0].name
        raise ColmapError(f"{where}: none of the photos of the model's {len(registered)} "
                          f"registered images is there ({first}: {missing[first]})")
    if found:
        ratios = [(p.size[0] / rec.cameras[im.camera_id].width,
                   p.size[1] / rec.cameras[im.camera_id].height)
                  for im in registered if (p := found.get(im.name)) is not None]
        folder_scale = tuple(float(v) for v in np.median(np.array(ratios), axis=0))
    else:
        folder_scale = (1.0 / folder_factor(image_folder),) * 2
    lap("check_photos")
    report(0.05, f"{len(found)} of {len(registered)} photos found")

    options = pycolmap.UndistortCameraOptions()
    cameras_file = model_file(model_dir, "cameras")
    intrinsics = {cid: pinhole_of(rec.cameras[cid], options, cameras_file)
                  for cid in sorted({im.camera_id for im in registered})}
    dropped = {"points3D": 0, "observations": 0}
    images: list[ColmapImage] = []
    for im in registered:
        intr, cam, photo = intrinsics[im.camera_id], rec.cameras[im.camera_id], found.get(im.name)
        if photo is not None:
            sx, sy = photo.size[0] / cam.width, photo.size[1] / cam.height
        else:
            sx, sy = folder_scale
        size = scaled_size(intr, sx, sy, photo.size if photo is not None else None)
        w2c = np.eye(4)
        w2c[:3, :] = im.cam_from_world().matrix()
        check_pose(w2c, images_file, im.name)
        try:
            camera = pinhole_camera(intr, size, w2c)
        except ValueError as error:  # Camera's own checks (a pose that is not rigid, ...)
            raise ColmapError(f"{images_file}: image {im.name!r}: {error}") from error
        observations = im.get_observation_points2D()
        xy = np.array([p.xy for p in observations], np.float64).reshape(-1, 2)
        ids = np.array([p.point3D_id for p in observations], np.uint64)
        check_point_ids(ids, images_file)
        usable = np.isfinite(xy).all(axis=1)
        dropped["observations"] += int(np.count_nonzero(~usable))
        xy, ids = xy[usable], ids[usable].astype(np.int64)
        as_is = photo is not None and not intr.distorted and photo.orientation == 1
        images.append(ColmapImage(
            image_id=int(im.image_id), name=im.name, camera_id=int(im.camera_id), camera=camera,
            path=photo.source if as_is else None,
            source_path=image_dir / im.name if image_dir is not None else None,
            points2D=undistort_points(intr, camera, xy), point3D_ids=ids))
    points = points_of(rec, points_file, dropped)
    lap("cameras_points")

    undistorted_dir = None
    distorted = any(i.distorted for i in intrinsics.values())
    copies = [im for im in images if im.name in found and im.path is None]
    if distorted or copies:
        key = cache_key(model_dir, image_dir, options)
        undistorted_dir = choose_cache(cache_dir, model_dir, image_dir, image_folder, key)
        if copy_photos:
            write_photo_copies(copies, intrinsics, found, undistorted_dir, threads,
                               lambda f, m: report(0.1 + 0.85 * f, m))
            lap("undistort_photos")
        if distorted:
            write_undistorted_model(rec, registered, images, intrinsics, undistorted_dir)
            lap("write_undistorted_model")

    scene = ColmapScene(
        model_dir=model_dir, image_dir=image_dir, image_folder=str(image_folder), images=images,
        points=points, missing=missing,
        camera_models={cid: intr.model for cid, intr in intrinsics.items()},
        undistorted_dir=undistorted_dir, timings=timings,
        dropped={what: n for what, n in dropped.items() if n})
    if align:
        scene = scene.aligned(up=up, scene_size=scene_size)
        lap("align")
    scene.timings = timings
    timings["total"] = time.perf_counter() - start
    report(1.0, "done")
    return scene


def points_of(rec, points_file: Path, dropped: dict[str, int]) -> ColmapPoints:
    """The sparse points sorted by id; points with a non-finite position or error are left out
    and counted in `dropped["points3D"]`."""
    items = list(rec.points3D.items())
    n = len(items)
    ids = np.fromiter((pid for pid, _ in items), np.uint64, n)
    check_point_ids(ids, points_file)
    xyz = np.array([p.xyz for _, p in items], np.float64).reshape(n, 3)
    rgb = np.array([p.color for _, p in items], np.uint8).reshape(n, 3)
    error = np.fromiter((p.error for _, p in items), np.float64, n)
    track = np.fromiter((p.track.length() for _, p in items), np.int32, n)
    usable = np.isfinite(xyz).all(axis=1) & np.isfinite(error)
    dropped["points3D"] += int(np.count_nonzero(~usable))
    ids = ids.astype(np.int64)
    order = np.argsort(ids)
    order = order[usable[order]]
    return ColmapPoints(ids[order], xyz[order], rgb[order], error[order], track[order])
