"""The cache of undistorted (or turned upright) photos and the undistorted model: where it is,
its key, and writing the photos into it (reusing valid earlier copies)."""

from __future__ import annotations

import hashlib
import json
import os
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Callable

from ..images import files
from ..atomic import atomic_write
from .checks import inside
from .errors import ColmapError
from .model import MODEL_FILES, Photo
from .scene import ColmapImage
from .undistort import PinholeIntrinsics, undistortion_map

CACHE_VERSION = 1

Progress = Callable[[float, str], None]

def user_cache_dir() -> Path:
    """A per-user cache folder for undistorted photos (not the temporary folder: it survives)."""
    if sys.platform == "win32":
        base = Path(os.environ.get("LOCALAPPDATA", Path.home() / "AppData" / "Local"))
    elif sys.platform == "darwin":
        base = Path.home() / "Library" / "Caches"
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    return base / "gaussian-splatting" / "colmap"


def _writable(folder: Path) -> bool:
    """Can we create files in `folder` (made if needed)? A folder whose nearest existing
    ancestor has no write permission bit at all counts as read-only even for a superuser,
    who could write there anyway: read-only input stays untouched."""
    existing = folder
    while not existing.exists() and existing.parent != existing:
        existing = existing.parent
    try:
        if not existing.stat().st_mode & 0o222:
            return False
        folder.mkdir(parents=True, exist_ok=True)
        probe = tempfile.NamedTemporaryFile(dir=folder, prefix=".probe", delete=True)
        probe.close()
        return True
    except OSError:
        return False


def cache_key(model_dir: Path, image_dir: Path | None, options) -> str:
    h = hashlib.sha1()
    h.update(f"v{CACHE_VERSION}".encode())
    for f in sorted(model_dir.iterdir()):
        if f.is_file() and f.stem in (*MODEL_FILES, "rigs", "frames"):
            st = f.stat()
            h.update(f"{f.name}:{st.st_size}:{st.st_mtime_ns}".encode())
    h.update(str(image_dir.resolve() if image_dir else None).encode())
    h.update(str(options.summary()).encode())
    return h.hexdigest()[:16]


def choose_cache(cache_dir, model_dir: Path, image_dir: Path | None, image_folder: str,
                  key: str) -> Path:
    name = f"{Path(image_folder).name}-{key}"
    if cache_dir is not None:
        root = Path(cache_dir)
    else:
        workspace = image_dir.parent if image_dir is not None else model_dir
        root = workspace / "splat_cache"
        if not _writable(root):
            root = user_cache_dir()
    folder = root / name
    if not _writable(folder):
        raise ColmapError(f"{folder}: cannot write the undistorted photos' cache there; "
                          f"choose another cache folder")
    if image_dir is not None and folder.resolve() == image_dir.resolve():
        raise ColmapError(f"{folder}: the cache folder must not be the image folder")
    return folder


def write_photo_copies(images: list[ColmapImage], intrinsics: dict[int, PinholeIntrinsics],
                       found: dict[str, Photo], folder: Path, threads: int,
                       report: Progress) -> None:
    """Write the photos of `images` undistorted (distorted cameras) or turned upright into
    folder/images (same names and formats), reusing valid earlier copies; sets each `path`."""
    manifest_path = folder / "manifest.json"
    try:
        manifest = json.loads(manifest_path.read_text())
    except (OSError, ValueError):
        manifest = {}
    todo, done = [], {}
    for im in images:
        photo = found[im.name]
        st = photo.source.stat()
        cam = im.camera
        entry = [st.st_size, st.st_mtime_ns, photo.orientation, cam.width, cam.height,
                 cam.fx, cam.fy, cam.cx, cam.cy]
        out = inside(folder, f"images/{im.name}", folder, "undistorted copy")
        if manifest.get(im.name) == entry and out.is_file():
            im.path = out
            done[im.name] = entry
        else:
            todo.append((im, out, entry))

    def work(item):
        im, out, entry = item
        photo, intr = found[im.name], intrinsics[im.camera_id]
        if out.resolve() == photo.source.resolve():
            raise ColmapError(f"{out}: refusing to overwrite the input photo")
        pixels = files.read_pixels(photo.source, orientation=photo.orientation)
        if intr.distorted:
            x, y = undistortion_map(intr, im.camera, photo.size)
            pixels = files.remap_bilinear(pixels, x, y)
        files.write_pixels(out, pixels)
        return item

    workers = threads if threads > 0 else (os.cpu_count() or 1)
    try:
        if todo:
            with ThreadPoolExecutor(max_workers=min(workers, len(todo))) as pool:
                for k, (im, out, entry) in enumerate(pool.map(work, todo)):
                    im.path = out
                    done[im.name] = entry
                    report((k + 1) / len(todo), f"undistorted {im.name}")
    except files.ImageError as error:
        raise ColmapError(str(error)) from error
    finally:
        if done:
            manifest.update(done)
            with atomic_write(inside(folder, "manifest.json", folder, "manifest")) as f:
                f.write(json.dumps(manifest).encode())


