"""A training dataset from a COLMAP scene: cameras, photos, train/test split, points.

    scene = colmap.read_colmap("workspace", "images_4", align=True)
    data = ColmapDataset(scene, downscale=2)
    for i in data.train_indices:
        camera, rgb = data.cameras[i], data.image(i)   # Camera, (H, W, 3) float32

- Only the registered images whose photo is usable (`ColmapScene.with_photos`), sorted by
  name, are in the dataset; `scene.missing` says which are not and why.
- Split: the literature's protocol (the 3DGS code's `llffhold`): sorted by name, every
  `test_every`-th image (index 0, 8, 16, ...) is held out for testing; `test_every=0` trains
  on everything.
- `downscale` divides the photos (and cameras) by a factor: size round(W / d) x round(H / d),
  cameras scaled per axis by the exact size ratio, photos box-filtered by OpenImageIO.
- `max_width`: as the reference 3DGS code does by default, a photo wider than this (1,600
  pixels) is trained at this width, whatever `downscale` leaves (0: no limit). A step costs
  about its pixel count, so a phone's 4,000x3,000 photo would cost 4.7x the time of 1,600x1,200.
- Photos are decoded lazily, on first use, and kept in memory in their file's own type
  (uint8 photos cost one byte a channel); `preload()` decodes them all on several threads
  (OpenImageIO releases the GIL). `max_cache_bytes` bounds the memory (least recently used
  photos are dropped first).
- `image(i)` returns float32 RGB: 8/16-bit photos normalised to [0, 1] (display sRGB as
  stored), float photos (EXR) as they are. Grey photos are repeated to RGB; `alpha(i)` is
  the alpha channel or None.

Blender-free.
"""

from __future__ import annotations

import os
import threading
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from ..images import files
from ..cameras import Camera
from ..colmap import ColmapImage, ColmapPoints, ColmapScene


def scale_camera(camera: Camera, width: int, height: int) -> Camera:
    """`camera` for its image resized to width x height (pixel-edge convention: exact)."""
    kx, ky = width / camera.width, height / camera.height
    return replace(camera, fx=camera.fx * kx, fy=camera.fy * ky, cx=camera.cx * kx,
                   cy=camera.cy * ky, width=int(width), height=int(height))


def split_indices(count: int, test_every: int = 8) -> tuple[list[int], list[int]]:
    """(train, test) indices: every `test_every`-th from 0 is a test view (0: none)."""
    if test_every < 0:
        raise ValueError(f"test_every must be >= 0, got {test_every}")
    test = list(range(0, count, test_every)) if test_every else []
    held = set(test)
    return [i for i in range(count) if i not in held], test


NO_CAMERA = "no camera object with this colmap_image_name in the scene"


@dataclass
class Points:
    """Points to start training from."""

    xyz: np.ndarray  # (N, 3) float64
    rgb: np.ndarray  # (N, 3): float64 in [0, 1], or uint8; display sRGB


def with_cameras(scene: ColmapScene, cameras: dict[str, Camera],
                 points: ColmapPoints | Points | None = None) -> ColmapScene:
    """`scene` with each image's camera replaced by `cameras[name]` (what the camera object
    with that `colmap_image_name` renders, at any size of the photo's aspect: it is scaled to
    the photo's pixels), and with `points` when given. Images with no camera are left out
    (listed in `missing`). Raises ValueError when no camera matches, or when a camera's frame
    does not have its photo's shape."""
    images, missing = [], dict(scene.missing)
    for im in scene.images:
        camera = cameras.get(im.name)
        if camera is None:
            missing[im.name] = NO_CAMERA
            continue
        size = im.camera.width, im.camera.height
        if abs(camera.width * size[1] - camera.height * size[0]) > 0.01 * camera.height * size[0]:
            raise ValueError(f"the camera of {im.name!r} renders {camera.width}x"
                             f"{camera.height} pixels but its photo is {size[0]}x{size[1]}")
        if (camera.width, camera.height) != size:
            camera = scale_camera(camera, *size)
        images.append(replace(im, camera=camera))
    if not images:
        raise ValueError(f"{scene.model_dir}: none of the model's images has a camera object "
                         f"in the scene (matched by colmap_image_name)")
    return replace(scene, images=images, missing=missing,
                   points=scene.points if points is None else points)


class Views:
    """The train/test split of a dataset's `cameras` (shared by every dataset type)."""

    cameras: list[Camera]
    train_indices: list[int]
    test_indices: list[int]
    # Whether image(i) gives the same pixels every time: the trainer then keeps the halved
    # photos of its coarse steps instead of making them again each step.
    fixed_images: bool = True

    def __len__(self) -> int:
        return len(self.cameras)

    @property
    def train_cameras(self) -> list[Camera]:
        return [self.cameras[i] for i in self.train_indices]

    @property
    def test_cameras(self) -> list[Camera]:
        return [self.cameras[i] for i in self.test_indices]


MAX_WIDTH = 1600  # pixels: wider photos train at this width (the reference 3DGS code's rule)


class ColmapDataset(Views):
    def __init__(self, scene: ColmapScene, *, downscale: float = 1.0, test_every: int = 8,
                 max_width: int = MAX_WIDTH, max_cache_bytes: int | None = None) -> None:
        if not downscale >= 1.0:
            raise ValueError(f"downscale must be at least 1, got {downscale}")
        if max_width < 0:
            raise ValueError(f"max_width must be >= 0 (0: no limit), got {max_width}")
        self.scene = scene
        self.items: list[ColmapImage] = scene.with_photos
        if not self.items:
            raise ValueError(f"{scene.model_dir}: no registered image has a usable photo")
        self.downscale = float(downscale)
        self.cameras: list[Camera] = []
        for im in self.items:
            cam = im.camera
            factor = max(downscale, cam.width / max_width) if max_width else downscale
            size = (max(1, round(cam.width / factor)), max(1, round(cam.height / factor)))
            self.cameras.append(scale_camera(cam, *size) if factor != 1 else cam)
        self.train_indices, self.test_indices = split_indices(len(self.items), test_every)
        self.max_cache_bytes = max_cache_bytes
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()
        self._cache_bytes = 0
        self._lock = threading.Lock()

    @property
    def names(self) -> list[str]:
        return [im.name for im in self.items]

    @property
    def points(self) -> ColmapPoints | Points:
        return self.scene.points

    def pixels(self, i: int) -> np.ndarray:
        """The photo's pixels (H, W, C) in its own type, decoded once and cached."""
        with self._lock:
            cached = self._cache.get(i)
            if cached is not None:
                self._cache.move_to_end(i)
                return cached
        cam = self.cameras[i]
        pixels = files.read_pixels(self.items[i].path, size=(cam.width, cam.height))
        if pixels.shape[:2] != (cam.height, cam.width):
            raise files.ImageError(
                f"{self.items[i].path}: {pixels.shape[1]}x{pixels.shape[0]} pixels, "
                f"expected {cam.width}x{cam.height}")
        with self._lock:
            if i not in self._cache:
                self._cache[i] = pixels
                self._cache_bytes += pixels.nbytes
                self._evict()
        return pixels

    def _evict(self) -> None:
        if self.max_cache_bytes is None:
            return
        while self._cache_bytes > self.max_cache_bytes and len(self._cache) > 1:
            _, old = self._cache.popitem(last=False)
            self._cache_bytes -= old.nbytes

    def image(self, i: int, *, threads: int = 0) -> np.ndarray:
        """(H, W, 3) float32 colour of image i (see the module docstring for its scale); 8-bit
        photos convert on `threads` threads (0: every core)."""
        return files.rgb_float(self.pixels(i), threads=threads)

    def alpha(self, i: int) -> np.ndarray | None:
        """(H, W) float32 alpha of image i, or None when the photo has none."""
        alpha = files.rgb_alpha(self.pixels(i))[1]
        return None if alpha is None else files.to_float(alpha[:, :, None])[:, :, 0]

    def preload(self, threads: int = 0,
                progress: Callable[[float, str], None] | None = None) -> None:
        """Decode every photo now, on `threads` threads (0: every core), in batches:
        `progress(fraction, message)` is called before each and may raise to stop (only the
        batch under way is waited for)."""
        workers = threads if threads > 0 else (os.cpu_count() or 1)
        with ThreadPoolExecutor(max_workers=workers) as pool:
            for start in range(0, len(self), 4 * workers):
                batch = range(start, min(start + 4 * workers, len(self)))
                if progress is not None:
                    progress(start / len(self),
                             f"decoding photos {start + 1}-{batch[-1] + 1} of {len(self)}")
                list(pool.map(self.pixels, batch))

    @property
    def cached_bytes(self) -> int:
        return self._cache_bytes
