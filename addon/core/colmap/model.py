"""Finding a COLMAP model and its photos, and reading the model (pycolmap) after checking it."""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

from ..images import files
from .checks import check_binary_model, check_text_cameras, is_inside
from .errors import ColmapError, import_pycolmap

IMAGE_FOLDERS = ("images", "images_2", "images_4", "images_8")
MODEL_FILES = ("cameras", "images", "points3D")


# -- finding the model and the photos ---------------------------------------------------------

def model_format(folder: Path) -> str | None:
    for ext in (".bin", ".txt"):
        if all((folder / f"{name}{ext}").is_file() for name in MODEL_FILES):
            return ext
    return None


def find_model(path: str | os.PathLike) -> Path:
    """The model folder for `path`: the folder itself, or `sparse/0`, `sparse`, `0` in it
    (then the lowest-numbered model in `sparse/`)."""
    path = Path(path)
    if path.is_file():
        path = path.parent
    if not path.is_dir():
        raise ColmapError(f"{path}: no such folder")
    candidates = [path, path / "sparse" / "0", path / "sparse", path / "0"]
    sparse = path / "sparse"
    if sparse.is_dir():
        numbered = sorted((p for p in sparse.iterdir() if p.is_dir() and p.name.isdigit()),
                          key=lambda p: int(p.name))
        candidates += numbered
    for folder in candidates:
        if folder.is_dir() and model_format(folder):
            return folder
    partial = [f.name for folder in candidates if folder.is_dir() for f in folder.iterdir()
               if f.stem in MODEL_FILES and f.suffix in (".bin", ".txt")]
    if partial:
        raise ColmapError(
            f"{path}: incomplete COLMAP model (found {', '.join(sorted(set(partial)))}; "
            f"cameras, images and points3D are all needed, as .bin or .txt)")
    raise ColmapError(
        f"{path}: no COLMAP model (cameras, images, points3D as .bin or .txt) in it or in "
        f"its sparse/0 or sparse folder")


def find_image_dir(path: Path, model_dir: Path, image_folder: str) -> Path | None:
    """`image_folder` (absolute, or a name looked up beside the model: in `path`, the model
    folder and up to two folders above it)."""
    folder = Path(image_folder)
    if folder.is_absolute():
        return folder if folder.is_dir() else None
    path = path if path.is_dir() else path.parent
    for root in (path, model_dir, model_dir.parent, model_dir.parent.parent):
        if (root / folder).is_dir():
            return root / folder
    return None


def folder_factor(image_folder: str) -> int:
    match = re.search(r"_(\d+)$", Path(image_folder).name)
    return int(match.group(1)) if match else 1


def fits(photo: tuple[int, int], width: int, height: int) -> bool:
    """Can a photo of size `photo` show a width x height camera, scaled (any rounding)?"""
    w, h = photo
    return w > 0 and h > 0 and abs(w * height - h * width) <= width + height


@dataclass
class Photo:
    source: Path
    size: tuple[int, int]  # upright size, the one that matches the camera
    orientation: int  # EXIF orientation to apply to the stored pixels (1: none)


PHOTO_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".exr", ".webp", ".bmp")


def _not_a_file(path: Path) -> str | None:
    """Why `path` is no file to read ("not found", or what the OS said: a name too long for
    it, ...), or None when it is one. Never raises: names come from a stranger's model."""
    try:
        return None if path.is_file() else "not found"
    except (OSError, ValueError) as error:
        return f"cannot be opened: {getattr(error, 'strerror', None) or error}"


def renamed_photos(registered, image_dir: Path | None,
                   warnings: list[str] | None) -> dict[str, Path] | str | None:
    """LLFF-style folders (`images_4/image000.png`, ...) rename the photos in the sorted order
    of the model's names. When none of the model's names is in `image_dir`: the photos mapped
    in sorted order if their count is the model's (a warning appended to `warnings`), else the
    reason they cannot be matched (a str). None when some names are there (nothing renamed)."""
    if image_dir is None or not image_dir.is_dir() or any(
            _not_a_file(image_dir / im.name) is None for im in registered):
        return None
    files = sorted(p for p in image_dir.iterdir()
                   if p.is_file() and p.suffix.lower() in PHOTO_SUFFIXES)
    if len(files) != len(registered):
        return (f"no photo in {image_dir} has a model image's name, and its {len(files)} "
                f"photos cannot stand for the {len(registered)} registered images in sorted "
                f"order (the counts differ)")
    if warnings is not None:
        warnings.append(
            f"{image_dir}: no photo has a model image's name; its {len(files)} photos were "
            f"matched to the {len(registered)} registered images in sorted name order "
            f"({files[0].name} is {registered[0].name}), as LLFF-style folders are made")
    return {im.name: path for im, path in zip(registered, files)}


def find_photos(registered, rec, image_dir: Path | None,
                warnings: list[str] | None = None) -> tuple[dict[str, Photo], dict[str, str]]:
    """The photos of the `registered` images that fit their cameras, and why the others do not.
    Names were checked on reading (`checks.image_name`); a photo that is a link leading outside
    `image_dir` is not read (missing, with the reason)."""
    found, missing = {}, {}
    renamed = renamed_photos(registered, image_dir, warnings)
    if isinstance(renamed, str):
        return found, {im.name: renamed for im in registered}
    for im in registered:
        src = image_dir / im.name if image_dir is not None else None
        if renamed is not None:
            src = renamed[im.name]
        problem = "not found" if src is None else _not_a_file(src)
        if problem is not None:
            missing[im.name] = problem
            continue
        if not is_inside(image_dir, src):
            missing[im.name] = f"it is a link leading outside {image_dir}; refused"
            continue
        try:
            header = files.read_header(src)
        except files.ImageError as error:
            missing[im.name] = str(error)
            continue
        cam = rec.cameras[im.camera_id]
        if fits(header.size(False), cam.width, cam.height):
            found[im.name] = Photo(src, header.size(False), 1)
        elif header.orientation != 1 and fits(header.size(True), cam.width, cam.height):
            found[im.name] = Photo(src, header.size(True), header.orientation)
        else:
            w, h = header.size(False)
            missing[im.name] = f"its size {w}x{h} does not fit its camera's {cam.width}x{cam.height}"
    return found, missing


def read_reconstruction(model_dir: Path):
    """pycolmap's Reconstruction of a model folder, after the structural check."""
    pycolmap = import_pycolmap()
    model_dir = Path(model_dir)
    fmt = model_format(model_dir)
    if fmt is None:
        raise ColmapError(f"{model_dir}: no COLMAP model (cameras, images, points3D)")
    if fmt == ".bin":
        check_binary_model(model_dir)
    else:
        check_text_cameras(model_dir / "cameras.txt")
    rec = pycolmap.Reconstruction()
    try:
        if fmt == ".bin":
            rec.read_binary(str(model_dir))
        else:
            rec.read_text(str(model_dir))
    except Exception as error:  # noqa: BLE001 - pycolmap raises several types
        raise ColmapError(f"{model_dir}: cannot read the COLMAP model: {error}") from error
    return rec
