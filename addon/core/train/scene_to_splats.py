"""A Blender scene to splats (the "Bake to Splats" operator), the Blender-free part: cameras
around an object, surface points to start from, and an in-memory training dataset of RGBA
renders. (`addon/blender/train/scene_to_splats.py` renders the views with Cycles and runs the
training; splats -> a mesh texture is `addon/core/mesh/texture.py`.)

- `sphere_directions(n)`: n unit vectors spread evenly over the sphere (a Fibonacci lattice), or
  over the upper half (`upper_only`, z > 0) for things standing on the ground.
- `orbit_cameras(centre, radius, n, width, height, distance_factor)`: pinhole cameras (our OpenCV
  convention) on a sphere of `distance_factor * radius` around `centre`, each looking at it, with
  square pixels and a field of view that holds the bounding sphere with a 10 % margin.
- `sample_surface(vertices, triangles, colours, n, rng)`: points spread uniformly over triangles
  (area-weighted), with their triangle's colour.
- `ImageDataset`: the dataset interface `Trainer` needs (`cameras`, `train_indices`,
  `test_indices`, `train_cameras`, `image(i)`, `points.xyz/.rgb`) over premultiplied RGBA
  targets. `image(i)` composites the target over `dataset.background` (black by default);
  `RandomBackground` changes that colour (and the trainer's) before every step, so the splats
  must match the targets' alpha too: where a target is transparent no colour is free, and the
  Gaussians learn to be absent rather than black. Evaluation afterwards is over black.

Colours are display sRGB in [0, 1], like photos (docs/conventions.md, "Colour"); converting Blender's
scene-linear renders to that is `addon.core.colour.display_from_linear`.
"""

from __future__ import annotations

import math

import numpy as np

from ..cameras import Camera
from .dataset import Points, Views, split_indices

GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))


def sphere_directions(count: int, *, upper_only: bool = False) -> np.ndarray:
    """(count, 3) unit vectors of a Fibonacci lattice: z evenly spaced in (-1, 1) (or (0, 1)),
    longitude advancing by the golden angle. No point lies exactly on a pole."""
    if count < 1:
        raise ValueError(f"need at least one direction, got {count}")
    i = np.arange(count, dtype=np.float64)
    z = 1.0 - (i + 0.5) / count if upper_only else 1.0 - 2.0 * (i + 0.5) / count
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    phi = GOLDEN_ANGLE * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def orbit_cameras(centre, radius: float, count: int, width: int, height: int, *,
                  distance_factor: float = 2.5, upper_only: bool = False,
                  margin: float = 1.1) -> list[Camera]:
    """Cameras at `centre + distance_factor * radius * d` for the directions `d` of
    `sphere_directions`, looking at `centre` with +Z up in the image (any perpendicular when
    looking straight up or down). The bounding sphere of `radius` subtends a half-angle
    asin(1 / distance_factor); the shorter image side sees `margin` times that."""
    if not radius > 0 or not math.isfinite(radius):
        raise ValueError(f"the bounding radius must be positive and finite, got {radius}")
    if not distance_factor > 1.0:
        raise ValueError(f"distance_factor must be above 1 (cameras outside the bounding "
                         f"sphere), got {distance_factor}")
    centre = np.asarray(centre, np.float64)
    half = min(math.asin(1.0 / distance_factor) * margin, math.radians(80.0))
    focal = 0.5 * min(width, height) / math.tan(half)
    fov_x = math.degrees(2.0 * math.atan(0.5 * width / focal))
    cameras = []
    for d in sphere_directions(count, upper_only=upper_only):
        eye = centre + distance_factor * radius * d
        cameras.append(Camera.look_at(eye, centre, (0.0, 0.0, 1.0), width=width, height=height,
                                      fov_x_degrees=fov_x))
    return cameras


def sample_surface(vertices: np.ndarray, triangles: np.ndarray, colours: np.ndarray | None,
                   count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """`count` points uniformly distributed over the triangles' total area, and their colours
    ((T, 3) per triangle, or grey when None). Returns (xyz (count, 3), rgb (count, 3)) float64."""
    vertices = np.asarray(vertices, np.float64).reshape(-1, 3)
    triangles = np.asarray(triangles, np.int64).reshape(-1, 3)
    if len(triangles) == 0 or count < 1:
        return np.zeros((0, 3)), np.zeros((0, 3))
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    total = area.sum()
    if not total > 0:
        raise ValueError("the surfaces have no area to sample")
    which = rng.choice(len(triangles), size=count, p=area / total)
    u, v = rng.random(count), rng.random(count)
    flip = u + v > 1.0  # fold the unit square onto the triangle: uniform barycentrics
    u[flip], v[flip] = 1.0 - u[flip], 1.0 - v[flip]
    xyz = a[which] + u[:, None] * (b - a)[which] + v[:, None] * (c - a)[which]
    if colours is None:
        rgb = np.full((count, 3), 0.5)
    else:
        rgb = np.clip(np.asarray(colours, np.float64).reshape(-1, 3)[which], 0.0, 1.0)
    return xyz, rgb


class ImageDataset(Views):
    """Training views held in memory: cameras and premultiplied display-sRGB RGBA targets."""

    fixed_images = False  # composited over `background`, which a bake draws anew each step

    def __init__(self, cameras: list[Camera], rgba: list[np.ndarray], points: Points, *,
                 test_every: int = 0, names: list[str] | None = None) -> None:
        if len(cameras) != len(rgba) or not cameras:
            raise ValueError(f"need one RGBA image per camera, got {len(cameras)} cameras and "
                             f"{len(rgba)} images")
        self.cameras = list(cameras)
        self.rgba = []
        for camera, image in zip(cameras, rgba):
            image = np.ascontiguousarray(image, np.float32)
            if image.shape != (camera.height, camera.width, 4):
                raise ValueError(f"image of shape {image.shape} for a {camera.width}x"
                                 f"{camera.height} camera (expected RGBA)")
            self.rgba.append(image)
        self.points = points
        self.names = names or [f"view_{i:03d}" for i in range(len(cameras))]
        self.train_indices, self.test_indices = split_indices(len(cameras), test_every)
        self.background = np.zeros(3, np.float32)

    def image(self, i: int, *, threads: int = 0) -> np.ndarray:
        """(H, W, 3) float32: the premultiplied target over `self.background` (`threads`: as
        ColmapDataset.image takes it; unused)."""
        rgba = self.rgba[i]
        return rgba[..., :3] + (1.0 - rgba[..., 3:4]) * self.background

    def alpha(self, i: int) -> np.ndarray:
        return self.rgba[i][..., 3]


class RandomBackground:
    """A `TrainingJob.before_step` hook: a fresh uniformly random background colour for the
    dataset's targets and the trainer's render before each step (deterministic for a seed).
    `finish(trainer)` puts both back to black."""

    def __init__(self, dataset: ImageDataset, seed: int = 0) -> None:
        self.dataset = dataset
        self.rng = np.random.default_rng(seed)

    def __call__(self, trainer) -> None:
        colour = self.rng.random(3).astype(np.float32)
        self.dataset.background[:] = colour
        trainer.background[:] = colour

    def finish(self, trainer) -> None:
        self.dataset.background[:] = 0.0
        trainer.background[:] = 0.0
