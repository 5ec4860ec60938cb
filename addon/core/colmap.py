"""COLMAP scenes: reading (through pycolmap 4.x), undistortion to pinhole, alignment.

`read_colmap(path, image_folder="images", ...)` takes a model folder (cameras, images,
points3D as .bin or .txt; COLMAP 4's rigs and frames files too) or a workspace folder
(`sparse/0`, `sparse`, and the image folders beside it) and returns a `ColmapScene`:

- one `ColmapImage` per *registered* image, sorted by name (names keep their subfolders), each
  with a pinhole `Camera` (our OpenCV convention: COLMAP's `cam_from_world` is exactly
  `Camera.world_to_camera`, and COLMAP's pixel centres are at i + 0.5 like ours) sized for the
  chosen image folder, its observations of 3D points in that camera's pixels, and the path of
  the photo that matches the camera (`None` where the photo is missing);
- the sparse points (`ColmapPoints`: xyz, colour, error, track length);
- `missing`: the registered images whose photos are not usable, with the reason;
- `world_from_colmap`: the similarity from COLMAP's frame to the scene's (identity unless
  aligned), so anything can be mapped back.

Image folders. `images_2/4/8` hold downscaled photos, possibly only some of them. Each photo's
camera is scaled by its own size ratio (photo size / COLMAP camera size, per axis: exact under
the pixel-edge convention); a missing photo's camera is scaled by the folder's ratio (from the
photos that are there, else the folder name's `_N`). A photo whose size fits neither the
camera nor the camera turned by its EXIF orientation is reported as missing.

Distorted cameras (every COLMAP model other than SIMPLE_PINHOLE and PINHOLE) are undistorted
to pinhole with pycolmap: `undistort_camera` at COLMAP's resolution chooses the pinhole camera
(and its crop, no blank pixels), which is then scaled like any other camera; observations go
through pycolmap's `Camera.cam_from_img`, photos through the same mapping (bilinear, every bit
depth, see `photos.remap_bilinear`; it agrees with pycolmap's `undistort_image`). Undistorted
photos (and upright copies of photos stored sideways with an EXIF orientation), with the
undistorted model (a COLMAP workspace of its own: `images/`, `sparse/0/`), are cached in
`cache_dir`, by default `<workspace>/splat_cache/` when that is writable, else a user cache
folder; the input is never written.

Alignment (`align=True` or `ColmapScene.aligned()`): rotate so that the scene stands upright
(Blender's +Z up), then centre and scale it; see `alignment`.

Bad input raises `ColmapError` (a `ValueError`) naming the file and the problem. Binary models
are checked structurally before pycolmap reads them: a corrupt count in a .bin file otherwise
makes pycolmap allocate gigabytes or loop for minutes.

Blender-free: numpy, pycolmap and OpenImageIO only.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import struct
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from . import photos
from .cameras import Camera

IMAGE_FOLDERS = ("images", "images_2", "images_4", "images_8")
PINHOLE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE")
MODEL_FILES = ("cameras", "images", "points3D")
DEFAULT_SCENE_SIZE = 4.0
CACHE_VERSION = 1

Progress = Callable[[float, str], None]


class ColmapError(ValueError):
    """Bad or unusable COLMAP input; the message names the file or folder and the problem."""


def _shared_gflags_loaded() -> bool:
    """Whether this process has a shared libgflags loaded (Linux distributions' Blender builds
    link the system's glog/gflags). pycolmap's own glog then registers its flags a second time
    in that library, and gflags ends the process: Debian's Blender 5.2 quits on `import pycolmap`."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as maps:
            return "/libgflags" in maps.read()
    except OSError:
        return False


def _pycolmap():
    if "pycolmap" not in sys.modules and _shared_gflags_loaded():
        raise ColmapError(
            "COLMAP import and training need pycolmap, which cannot be loaded in this Blender: "
            "it uses the system's glog/gflags libraries (a Linux distribution's build), and "
            "loading pycolmap beside them would close Blender. Use Blender from blender.org")
    try:
        import pycolmap
    except ImportError as error:
        raise ColmapError(
            "COLMAP import and training need pycolmap 4.x, which this Blender cannot load "
            f"({error}): PyPI has no pycolmap for this platform or Python version, so the "
            "extension could not bundle one (README: Installation)") from error
    return pycolmap


# -- data -------------------------------------------------------------------------------------

@dataclass
class ColmapImage:
    image_id: int
    name: str  # COLMAP's image name, with its subfolders ("a/b.jpg")
    camera_id: int
    camera: Camera  # pinhole, in the scene's frame, in the pixels of `path`
    path: Path | None  # photo whose stored pixels match `camera` (original, or the cache's
    #                    undistorted or upright copy); None where there is none
    source_path: Path | None  # where the original photo is (or would be)
    points2D: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (M, 2) pixels
    point3D_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # (M,)


@dataclass
class ColmapPoints:
    ids: np.ndarray  # (N,) int64, COLMAP point3D ids
    xyz: np.ndarray  # (N, 3) float64, in the scene's frame
    rgb: np.ndarray  # (N, 3) uint8, sRGB
    error: np.ndarray  # (N,) float64, mean reprojection error in COLMAP's pixels
    track_length: np.ndarray  # (N,) int32, number of observations

    def __len__(self) -> int:
        return len(self.ids)

    def positions_of(self, ids) -> np.ndarray:
        """Row of each point id in these arrays (-1 where absent). `ids` is sorted on read."""
        ids = np.asarray(ids, np.int64)
        if len(self.ids) == 0:
            return np.full(ids.shape, -1, np.int64)
        rows = np.clip(np.searchsorted(self.ids, ids), 0, len(self.ids) - 1)
        return np.where(self.ids[rows] == ids, rows, -1)


@dataclass
class ColmapScene:
    model_dir: Path
    image_dir: Path | None
    image_folder: str
    images: list[ColmapImage]  # registered images, sorted by name
    points: ColmapPoints
    missing: dict[str, str]  # image name -> why its photo is not usable
    camera_models: dict[int, str]  # COLMAP camera id -> its model name
    undistorted_dir: Path | None  # cache folder of the undistorted workspace, if any
    world_from_colmap: np.ndarray = field(default_factory=lambda: np.eye(4))
    alignment_info: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)  # seconds per step

    @property
    def with_photos(self) -> list[ColmapImage]:
        return [im for im in self.images if im.path is not None]

    @property
    def undistorted(self) -> bool:
        return any(m not in PINHOLE_MODELS for m in self.camera_models.values())

    def image(self, name: str) -> ColmapImage:
        for im in self.images:
            if im.name == name:
                return im
        raise KeyError(name)

    def transformed(self, similarity: np.ndarray) -> "ColmapScene":
        """The scene mapped by a similarity `x' = s R x + t` (4x4), cameras and points."""
        sim = np.asarray(similarity, np.float64)
        images = [replace(im, camera=transform_camera(im.camera, sim)) for im in self.images]
        points = replace(self.points, xyz=transform_points(self.points.xyz, sim))
        return replace(self, images=images, points=points,
                       world_from_colmap=sim @ self.world_from_colmap)

    def aligned(self, up: str = "auto", scene_size: float = DEFAULT_SCENE_SIZE) -> "ColmapScene":
        """Upright (+Z), centred and scaled: see `alignment`. Composes with any earlier one."""
        sim, info = alignment([im.camera for im in self.images], self.points.xyz, up=up,
                              scene_size=scene_size)
        out = self.transformed(sim)
        out.alignment_info = info
        return out

    def to_colmap(self, xyz: np.ndarray) -> np.ndarray:
        """Points of the scene's frame back in COLMAP's frame."""
        return transform_points(xyz, np.linalg.inv(self.world_from_colmap))


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


# -- finding the model and the photos ---------------------------------------------------------

def _model_format(folder: Path) -> str | None:
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
        if folder.is_dir() and _model_format(folder):
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


# -- structural check of binary models -------------------------------------------------------

def _num_params_by_model_id() -> dict[int, int]:
    pycolmap = _pycolmap()

    table = {}
    for name, model_id in pycolmap.CameraModelId.__members__.items():
        if name == "INVALID":
            continue
        try:
            cam = pycolmap.Camera.create_from_model_id(1, model_id, 1.0, 1, 1)
        except Exception:  # noqa: BLE001 - a model pycolmap cannot create is not supported
            continue
        table[int(model_id)] = len(cam.params)
    return table


def check_binary_model(model_dir: Path) -> None:
    """Walk the .bin files' structure: every count must fit in what is left of the file."""
    def fail(name: str, offset: int, what: str) -> None:
        raise ColmapError(f"{model_dir / name}: corrupt COLMAP binary file at byte {offset}: {what}")

    def u64(buf, off, name):
        if off + 8 > len(buf):
            fail(name, off, "file ends early")
        return struct.unpack_from("<Q", buf, off)[0]

    params = _num_params_by_model_id()
    name = "cameras.bin"
    buf = (model_dir / name).read_bytes()
    count, off = u64(buf, 0, name), 8
    if count * 24 > len(buf):
        fail(name, 0, f"{count} cameras cannot fit in {len(buf)} bytes")
    for _ in range(count):
        if off + 24 > len(buf):
            fail(name, off, "file ends early")
        model_id = struct.unpack_from("<i", buf, off + 4)[0]
        if model_id not in params:
            fail(name, off, f"unknown camera model id {model_id}")
        off += 24 + 8 * params[model_id]
    if off > len(buf):
        fail(name, off, "file ends early")

    name = "images.bin"
    buf = (model_dir / name).read_bytes()
    count, off = u64(buf, 0, name), 8
    if count * 73 > len(buf):
        fail(name, 0, f"{count} images cannot fit in {len(buf)} bytes")
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
    buf = (model_dir / name).read_bytes()
    count, off = u64(buf, 0, name), 8
    if count * 51 > len(buf):
        fail(name, 0, f"{count} points cannot fit in {len(buf)} bytes")
    unpack = struct.Struct("<Q").unpack_from
    size = len(buf)
    for _ in range(count):
        if off + 51 > size:
            fail(name, off, "file ends early")
        n = unpack(buf, off + 43)[0]
        off += 51 + 8 * n
        if off > size:
            fail(name, off - 8 * n - 8, f"a track of {n} observations cannot fit in the file")

    for name, record in (("rigs.bin", 16), ("frames.bin", 68)):
        if (model_dir / name).is_file():
            buf = (model_dir / name).read_bytes()
            count = u64(buf, 0, name)
            if count * record > len(buf):
                fail(name, 0, f"{count} entries cannot fit in {len(buf)} bytes")


def read_reconstruction(model_dir: Path):
    """pycolmap's Reconstruction of a model folder, after the structural check."""
    pycolmap = _pycolmap()

    model_dir = Path(model_dir)
    fmt = _model_format(model_dir)
    if fmt is None:
        raise ColmapError(f"{model_dir}: no COLMAP model (cameras, images, points3D)")
    if fmt == ".bin":
        check_binary_model(model_dir)
    rec = pycolmap.Reconstruction()
    try:
        if fmt == ".bin":
            rec.read_binary(str(model_dir))
        else:
            rec.read_text(str(model_dir))
    except Exception as error:  # noqa: BLE001 - pycolmap raises several types
        raise ColmapError(f"{model_dir}: cannot read the COLMAP model: {error}") from error
    return rec


# -- cameras ---------------------------------------------------------------------------------

@dataclass
class _Intrinsics:
    """A COLMAP camera's pinhole replacement at COLMAP's resolution, and its source."""
    source: object  # pycolmap.Camera (distorted or not)
    model: str
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    @property
    def distorted(self) -> bool:
        return self.model not in PINHOLE_MODELS


def _pinhole_of(camera, options) -> _Intrinsics:
    pycolmap = _pycolmap()

    model = camera.model.name
    if model == "SIMPLE_PINHOLE":
        f, cx, cy = camera.params
        return _Intrinsics(camera, model, f, f, cx, cy, camera.width, camera.height)
    if model == "PINHOLE":
        fx, fy, cx, cy = camera.params
        return _Intrinsics(camera, model, fx, fy, cx, cy, camera.width, camera.height)
    if not camera.is_perspective():
        raise ColmapError(f"camera {camera.camera_id}: the {model} model has no pinhole "
                          f"equivalent (not a perspective camera)")
    try:
        pin = pycolmap.undistort_camera(options, camera)
    except Exception as error:  # noqa: BLE001
        raise ColmapError(f"camera {camera.camera_id} ({model}): cannot undistort: {error}") from error
    fx, fy, cx, cy = pin.params
    return _Intrinsics(camera, model, fx, fy, cx, cy, pin.width, pin.height)


def _scaled_size(intr: _Intrinsics, sx: float, sy: float, photo: tuple[int, int] | None) -> tuple[int, int]:
    if photo is not None and not intr.distorted:
        return photo
    return max(1, round(intr.width * sx)), max(1, round(intr.height * sy))


def _pinhole_camera(intr: _Intrinsics, size: tuple[int, int], w2c: np.ndarray) -> Camera:
    """Our Camera for intrinsics scaled to `size` (the pinhole image's size)."""
    kx, ky = size[0] / intr.width, size[1] / intr.height
    return Camera(w2c, intr.fx * kx, intr.fy * ky, intr.cx * kx, intr.cy * ky, size[0], size[1])


def _undistort_points(intr: _Intrinsics, camera: Camera, xy: np.ndarray) -> np.ndarray:
    """Pixels of COLMAP's (distorted, full-size) camera -> pixels of `camera`."""
    if len(xy) == 0:
        return np.zeros((0, 2))
    if intr.distorted:
        normalised = intr.source.cam_from_img(np.ascontiguousarray(xy, np.float64))
    else:
        normalised = np.stack([(xy[:, 0] - intr.cx) / intr.fx, (xy[:, 1] - intr.cy) / intr.fy], 1)
    return np.stack([camera.fx * normalised[:, 0] + camera.cx,
                     camera.fy * normalised[:, 1] + camera.cy], 1)


def undistortion_map(intr: _Intrinsics, camera: Camera, photo_size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """For each pixel centre of the pinhole `camera`: where it lies in the distorted photo of
    size `photo_size` (continuous coordinates, pixel centres at i + 0.5)."""
    u = (np.arange(camera.width) + 0.5 - camera.cx) / camera.fx
    v = (np.arange(camera.height) + 0.5 - camera.cy) / camera.fy
    uu, vv = np.meshgrid(u, v)
    rays = np.stack([uu.ravel(), vv.ravel(), np.ones(uu.size)], 1)
    xy = intr.source.img_from_cam(rays)  # COLMAP's full-size distorted pixels
    sx, sy = photo_size[0] / intr.source.width, photo_size[1] / intr.source.height
    return (xy[:, 0] * sx).reshape(uu.shape), (xy[:, 1] * sy).reshape(uu.shape)


# -- caching ---------------------------------------------------------------------------------

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


def _cache_key(model_dir: Path, image_dir: Path | None, options) -> str:
    h = hashlib.sha1()
    h.update(f"v{CACHE_VERSION}".encode())
    for f in sorted(model_dir.iterdir()):
        if f.is_file() and f.stem in (*MODEL_FILES, "rigs", "frames"):
            st = f.stat()
            h.update(f"{f.name}:{st.st_size}:{st.st_mtime_ns}".encode())
    h.update(str(image_dir.resolve() if image_dir else None).encode())
    h.update(str(options.summary()).encode())
    return h.hexdigest()[:16]


def _choose_cache(cache_dir, model_dir: Path, image_dir: Path | None, image_folder: str,
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


# -- reading ---------------------------------------------------------------------------------

def _folder_factor(image_folder: str) -> int:
    match = re.search(r"_(\d+)$", Path(image_folder).name)
    return int(match.group(1)) if match else 1


def _fits(photo: tuple[int, int], width: int, height: int) -> bool:
    """Can a photo of size `photo` show a width x height camera, scaled (any rounding)?"""
    w, h = photo
    return w > 0 and h > 0 and abs(w * height - h * width) <= width + height


@dataclass
class _Photo:
    source: Path
    size: tuple[int, int]  # upright size, the one that matches the camera
    orientation: int  # EXIF orientation to apply to the stored pixels (1: none)


def _find_photos(registered, rec, image_dir: Path | None) -> tuple[dict[str, _Photo], dict[str, str]]:
    found, missing = {}, {}
    for im in registered:
        src = image_dir / im.name if image_dir is not None else None
        if src is None or not src.is_file():
            missing[im.name] = "not found"
            continue
        try:
            header = photos.read_header(src)
        except photos.PhotoError as error:
            missing[im.name] = str(error)
            continue
        cam = rec.cameras[im.camera_id]
        if _fits(header.size(False), cam.width, cam.height):
            found[im.name] = _Photo(src, header.size(False), 1)
        elif header.orientation != 1 and _fits(header.size(True), cam.width, cam.height):
            found[im.name] = _Photo(src, header.size(True), header.orientation)
        else:
            w, h = header.size(False)
            missing[im.name] = f"its size {w}x{h} does not fit its camera's {cam.width}x{cam.height}"
    return found, missing


def read_colmap(path: str | os.PathLike, image_folder: str = "images", *,
                cache_dir: str | os.PathLike | None = None, require_photos: bool = True,
                copy_photos: bool = True, align: bool = False, up: str = "auto", scene_size: float = DEFAULT_SCENE_SIZE,
                threads: int = 0, progress: Progress | None = None) -> ColmapScene:
    """Read a COLMAP model or workspace; see the module docstring.

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
    pycolmap = _pycolmap()

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
    registered = sorted((im for im in rec.images.values() if im.has_pose), key=lambda im: im.name)
    if not registered:
        raise ColmapError(f"{model_dir}: the model has no registered images")
    lap("read_model")

    image_dir = find_image_dir(path, model_dir, image_folder)
    found, missing = _find_photos(registered, rec, image_dir)
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
        folder_scale = (1.0 / _folder_factor(image_folder),) * 2
    lap("check_photos")
    report(0.05, f"{len(found)} of {len(registered)} photos found")

    options = pycolmap.UndistortCameraOptions()
    intrinsics = {cid: _pinhole_of(rec.cameras[cid], options)
                  for cid in sorted({im.camera_id for im in registered})}
    images: list[ColmapImage] = []
    for im in registered:
        intr, cam, photo = intrinsics[im.camera_id], rec.cameras[im.camera_id], found.get(im.name)
        if photo is not None:
            sx, sy = photo.size[0] / cam.width, photo.size[1] / cam.height
        else:
            sx, sy = folder_scale
        size = _scaled_size(intr, sx, sy, photo.size if photo is not None else None)
        w2c = np.eye(4)
        w2c[:3, :] = im.cam_from_world().matrix()
        camera = _pinhole_camera(intr, size, w2c)
        observations = im.get_observation_points2D()
        xy = np.array([p.xy for p in observations], np.float64).reshape(-1, 2)
        ids = np.array([p.point3D_id for p in observations], np.int64)
        as_is = photo is not None and not intr.distorted and photo.orientation == 1
        images.append(ColmapImage(
            image_id=int(im.image_id), name=im.name, camera_id=int(im.camera_id), camera=camera,
            path=photo.source if as_is else None,
            source_path=image_dir / im.name if image_dir is not None else None,
            points2D=_undistort_points(intr, camera, xy), point3D_ids=ids))
    points = _points_of(rec)
    lap("cameras_points")

    undistorted_dir = None
    distorted = any(i.distorted for i in intrinsics.values())
    copies = [im for im in images if im.name in found and im.path is None]
    if distorted or copies:
        key = _cache_key(model_dir, image_dir, options)
        undistorted_dir = _choose_cache(cache_dir, model_dir, image_dir, image_folder, key)
        if copy_photos:
            _copy_photos(copies, intrinsics, found, undistorted_dir, threads,
                         lambda f, m: report(0.1 + 0.85 * f, m))
            lap("undistort_photos")
        if distorted:
            _write_undistorted_model(rec, registered, images, intrinsics, undistorted_dir)
            lap("write_undistorted_model")

    scene = ColmapScene(
        model_dir=model_dir, image_dir=image_dir, image_folder=str(image_folder), images=images,
        points=points, missing=missing,
        camera_models={cid: intr.model for cid, intr in intrinsics.items()},
        undistorted_dir=undistorted_dir, timings=timings)
    if align:
        scene = scene.aligned(up=up, scene_size=scene_size)
        lap("align")
    scene.timings = timings
    timings["total"] = time.perf_counter() - start
    report(1.0, "done")
    return scene


def _points_of(rec) -> ColmapPoints:
    items = list(rec.points3D.items())
    n = len(items)
    ids = np.fromiter((pid for pid, _ in items), np.int64, n)
    xyz = np.array([p.xyz for _, p in items], np.float64).reshape(n, 3)
    rgb = np.array([p.color for _, p in items], np.uint8).reshape(n, 3)
    error = np.fromiter((p.error for _, p in items), np.float64, n)
    track = np.fromiter((p.track.length() for _, p in items), np.int32, n)
    order = np.argsort(ids)
    return ColmapPoints(ids[order], xyz[order], rgb[order], error[order], track[order])


def _copy_photos(images: list[ColmapImage], intrinsics: dict[int, _Intrinsics],
                 found: dict[str, _Photo], folder: Path, threads: int, report: Progress) -> None:
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
        out = folder / "images" / im.name
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
        pixels = photos.read_pixels(photo.source, orientation=photo.orientation)
        if intr.distorted:
            x, y = undistortion_map(intr, im.camera, photo.size)
            pixels = photos.remap_bilinear(pixels, x, y)
        photos.write_pixels(out, pixels)
        return item

    workers = threads if threads > 0 else (os.cpu_count() or 1)
    try:
        if todo:
            with ThreadPoolExecutor(max_workers=min(workers, len(todo))) as pool:
                for k, (im, out, entry) in enumerate(pool.map(work, todo)):
                    im.path = out
                    done[im.name] = entry
                    report((k + 1) / len(todo), f"undistorted {im.name}")
    except photos.PhotoError as error:
        raise ColmapError(str(error)) from error
    finally:
        if done:
            manifest.update(done)
            tmp = manifest_path.with_name(".manifest.json.tmp")
            tmp.write_text(json.dumps(manifest))
            os.replace(tmp, manifest_path)


def _write_undistorted_model(rec, registered, images: list[ColmapImage],
                             intrinsics: dict[int, _Intrinsics], folder: Path) -> None:
    """The model with pinhole cameras and every 2D point moved accordingly, as COLMAP binary
    in folder/sparse/0 (with folder/images, a COLMAP workspace). One rig per camera."""
    pycolmap = _pycolmap()

    out = pycolmap.Reconstruction()
    camera_ids: dict[tuple, int] = {}
    for im, ours in zip(registered, images):
        cam = ours.camera
        key = (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy)
        if key not in camera_ids:
            camera_ids[key] = len(camera_ids) + 1
            out.add_camera_with_trivial_rig(pycolmap.Camera(
                camera_id=camera_ids[key], model="PINHOLE", width=cam.width, height=cam.height,
                params=[cam.fx, cam.fy, cam.cx, cam.cy]))
        xy = np.array([p.xy for p in im.points2D], np.float64).reshape(-1, 2)
        moved = _undistort_points(intrinsics[im.camera_id], cam, xy)
        image = pycolmap.Image(name=im.name, keypoints=moved, camera_id=camera_ids[key],
                               image_id=im.image_id)
        out.add_image_with_trivial_frame(image, im.cam_from_world())
    for pid, point in rec.points3D.items():
        out.add_point3D(point.xyz, pycolmap.Track(point.track.elements), point.color)
    out.update_point_3d_errors()
    target = folder / "sparse" / "0"
    target.mkdir(parents=True, exist_ok=True)
    try:
        out.write_binary(str(target))
    except Exception as error:  # noqa: BLE001
        raise ColmapError(f"{target}: cannot write the undistorted model: {error}") from error
