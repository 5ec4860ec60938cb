"""Checks on a COLMAP model from a stranger: what pycolmap must never see, and what must never
come out of it.

Before pycolmap reads a model: the binary files' structure (every count must fit in the file; a
corrupt count otherwise makes pycolmap allocate gigabytes or loop for minutes) and every
camera's size and parameters, binary or text (a distorted camera claiming a height of 2^64 - 1
hangs pycolmap's undistortion). After: image names (UTF-8, and inside the image folder: a
downloaded scene must never make us read or write outside the folders the user chose), finite
poses, point ids that fit int64. Non-finite points and observations are dropped and counted.
Every error is a `ColmapError` naming the file and the camera, image or point.
"""

from __future__ import annotations

import math
import struct
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..formats_common.contained import is_contained_name, unrepresentable  # the one judge of names in files
from .errors import ColmapError, import_pycolmap

# Camera sides up to Blender's own resolution limit; COLMAP cameras are photos' sizes.
MAX_CAMERA_SIDE = 65536
MAX_POINT_ID = 2**63 - 1  # ids are int64 in our arrays; COLMAP's invalid id is 2^64 - 1


@lru_cache(maxsize=1)
def camera_models() -> dict[int, tuple[str, int, tuple[int, ...]]]:
    """COLMAP camera model id -> (name, parameter count, indices of the focal lengths)."""
    pycolmap = import_pycolmap()
    table = {}
    for name, model_id in pycolmap.CameraModelId.__members__.items():
        if name == "INVALID":
            continue
        try:
            cam = pycolmap.Camera.create_from_model_id(1, model_id, 1.0, 1, 1)
        except Exception:  # noqa: BLE001 - a model pycolmap cannot create is not supported
            continue
        table[int(model_id)] = (name, len(cam.params), tuple(cam.focal_length_idxs()))
    return table


def check_camera(where: Path, camera_id: int, model: str, width: int, height: int,
                 params, focal_indices: tuple[int, ...]) -> None:
    """One camera's size and parameters, before pycolmap sees it."""
    what = f"{where}: camera {camera_id} ({model})"
    if not (1 <= width <= MAX_CAMERA_SIDE and 1 <= height <= MAX_CAMERA_SIDE):
        raise ColmapError(f"{what}: size {width}x{height} is outside 1..{MAX_CAMERA_SIDE} a side")
    if not all(math.isfinite(v) for v in params):
        raise ColmapError(f"{what}: non-finite parameters {list(params)}")
    if not all(params[i] > 0 for i in focal_indices):
        raise ColmapError(f"{what}: focal lengths must be positive, got "
                          f"{[params[i] for i in focal_indices]}")


def check_binary_model(model_dir: Path) -> None:
    """Walk the .bin files' structure (every count must fit in what is left of the file) and
    check every camera."""
    def fail(name: str, offset: int, what: str) -> None:
        raise ColmapError(f"{model_dir / name}: corrupt COLMAP binary file at byte {offset}: {what}")

    def u64(buf, off, name):
        if off + 8 > len(buf):
            fail(name, off, "file ends early")
        return struct.unpack_from("<Q", buf, off)[0]

    def counted(name: str, record: int, what: str) -> tuple[bytes, int]:
        buf = (model_dir / name).read_bytes()
        count = u64(buf, 0, name)
        if count * record > len(buf):
            fail(name, 0, f"{count} {what} cannot fit in {len(buf)} bytes")
        return buf, count

    models = camera_models()
    name = "cameras.bin"
    buf, count = counted(name, 24, "cameras")
    off = 8
    for _ in range(count):
        if off + 24 > len(buf):
            fail(name, off, "file ends early")
        camera_id, model_id, width, height = struct.unpack_from("<IiQQ", buf, off)
        if model_id not in models:
            fail(name, off, f"unknown camera model id {model_id}")
        model, n, focal = models[model_id]
        if off + 24 + 8 * n > len(buf):
            fail(name, off, "file ends early")
        params = struct.unpack_from(f"<{n}d", buf, off + 24)
        check_camera(model_dir / name, camera_id, model, width, height, params, focal)
        off += 24 + 8 * n

    name = "images.bin"
    buf, count = counted(name, 73, "images")
    off = 8
    for _ in range(count):
        end = buf.find(b"\0", off + 64)
        if off + 64 > len(buf) or end < 0:
            fail(name, off, "file ends early")
        n = u64(buf, end + 1, name)
        off = end + 9
        if n * 24 > len(buf) - off:
            fail(name, off - 8, f"{n} image points cannot fit in the rest of the file")
        off += 24 * n

    name = "points3D.bin"
    buf, count = counted(name, 51, "points")
    off = 8
    unpack = struct.Struct("<Q").unpack_from
    size = len(buf)
    for _ in range(count):
        if off + 51 > size:
            fail(name, off, "file ends early")
        n = unpack(buf, off + 43)[0]
        off += 51 + 8 * n
        if off > size:
            fail(name, off - 8 * n - 8, f"a track of {n} observations cannot fit in the file")

    # COLMAP 4's rigs and frames (optional): their inner counts hang pycolmap when they lie.
    name = "rigs.bin"
    if (model_dir / name).is_file():
        buf, count = counted(name, 8, "rigs")
        off = 8
        for _ in range(count):  # rig id, sensor count, reference sensor, then the others
            if off + 8 > len(buf):
                fail(name, off, "file ends early")
            sensors = struct.unpack_from("<I", buf, off + 4)[0]
            if sensors * 9 > len(buf) - off:
                fail(name, off, f"{sensors} sensors cannot fit in the rest of the file")
            off += 16 if sensors else 8
            for _ in range(max(0, sensors - 1)):  # type, id, has pose, [pose: 7 doubles]
                if off + 9 > len(buf):
                    fail(name, off, "file ends early")
                off += 9 + (56 if buf[off + 8] else 0)
        if off > len(buf):
            fail(name, off, "file ends early")
    name = "frames.bin"
    if (model_dir / name).is_file():
        buf, count = counted(name, 68, "frames")
        off = 8
        for _ in range(count):  # frame id, rig id, pose (7 doubles), data ids of 16 bytes
            if off + 68 > len(buf):
                fail(name, off, "file ends early")
            data_ids = struct.unpack_from("<I", buf, off + 64)[0]
            off += 68 + 16 * data_ids
            if off > len(buf):
                fail(name, off - 16 * data_ids, f"{data_ids} data ids cannot fit in the file")


def check_text_cameras(path: Path) -> None:
    """cameras.txt: `CAMERA_ID MODEL WIDTH HEIGHT PARAMS...` per line, checked like the binary
    ones (a line pycolmap would refuse anyway is left to pycolmap's own message)."""
    by_name = {name: (n, focal) for name, n, focal in camera_models().values()}
    try:
        lines = path.read_bytes().decode("utf-8", errors="replace").splitlines()
    except OSError as error:
        raise ColmapError(f"{path}: cannot read: {error.strerror or error}") from error
    for number, line in enumerate(lines, start=1):
        words = line.split()
        if not words or words[0].startswith("#") or len(words) < 4 or words[1] not in by_name:
            continue
        n, focal = by_name[words[1]]
        try:
            camera_id, width, height = int(words[0]), int(words[2]), int(words[3])
            params = [float(w) for w in words[4:4 + n]]
        except ValueError:
            raise ColmapError(f"{path}: line {number}: malformed camera {line.strip()[:80]!r}") from None
        if len(params) != n:
            raise ColmapError(f"{path}: line {number}: camera {camera_id} ({words[1]}) needs {n} "
                              f"parameters, got {len(params)}")
        check_camera(path, camera_id, words[1], width, height, params, focal)


def is_inside(root: Path, path: Path) -> bool:
    """Does `path`, links followed, lie inside `root` (links followed)? A path the OS cannot
    resolve (too long in all, a link loop) does not."""
    try:
        return Path(path).resolve().is_relative_to(Path(root).resolve())
    except (OSError, RuntimeError, ValueError):
        return False


def inside(root: Path, name: str, where: Path, what: str) -> Path:
    """`root / name`, refused (ColmapError naming `where` and `what`) unless it lies inside
    `root`: neither `..` nor a symbolic link takes it out."""
    if unrepresentable(name) is not None:
        raise ColmapError(f"{where}: {what}: {name[:200]!r}: {unrepresentable(name)}; refused")
    path = Path(root) / name
    if not is_contained_name(name) or not is_inside(root, path):
        raise ColmapError(f"{where}: {what}: {name!r} leads outside {root}; refused")
    return path


def image_name(image, images_file: Path) -> str:
    """A pycolmap image's name, refused unless it is UTF-8 and stays inside its folder."""
    try:
        name = image.name
    except UnicodeDecodeError:
        raise ColmapError(f"{images_file}: image {image.image_id}: its name is not UTF-8") from None
    problem = unrepresentable(name)
    if problem is not None:
        raise ColmapError(f"{images_file}: image {image.image_id} {name[:200]!r}: {problem}; refused")
    if not is_contained_name(name):
        raise ColmapError(f"{images_file}: image {image.image_id} {name!r}: the name leads outside "
                          f"the image folder; refused")
    return name


def check_pose(w2c: np.ndarray, images_file: Path, name: str) -> None:
    if not np.isfinite(w2c).all():
        raise ColmapError(f"{images_file}: image {name!r}: non-finite pose")


def check_point_ids(ids: np.ndarray, points_file: Path) -> None:
    """`ids` as uint64: each must fit int64."""
    if len(ids) and int(ids.max()) > MAX_POINT_ID:
        raise ColmapError(f"{points_file}: point3D id {int(ids.max())} is out of range "
                          f"(at most {MAX_POINT_ID})")


def model_file(model_dir: Path, stem: str) -> Path:
    """The model's `stem` file (.bin or .txt, whichever is there), for messages."""
    binary = Path(model_dir) / f"{stem}.bin"
    return binary if binary.is_file() else Path(model_dir) / f"{stem}.txt"


__all__ = ["MAX_CAMERA_SIDE", "MAX_POINT_ID", "camera_models", "check_camera", "check_binary_model",
           "check_text_cameras", "is_contained_name", "is_inside", "inside", "image_name", "check_pose",
           "check_point_ids", "model_file"]
