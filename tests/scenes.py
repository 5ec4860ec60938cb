"""Random test scenes: Gaussians mostly in front of a camera, with a spread of sizes, opacities,
orientations and SH colours, plus a few anywhere (behind the camera, far outside the view)."""

from __future__ import annotations

import math

import numpy as np

from addon.core.cameras import Camera
from addon.core.gaussians import Gaussians, sh_count
from addon.core.sh import SH_C0


def random_camera(rng: np.random.Generator, width: int, height: int, *,
                  target=(0.0, 0.0, 0.0), distance: float = 6.0) -> Camera:
    """A pinhole camera `distance` from `target` looking roughly at it, 40-80 degrees wide,
    with a slightly off-centre principal point and slightly non-square pixels."""
    target = np.asarray(target, np.float64)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    eye = target + distance * direction
    look = target + rng.normal(scale=0.2, size=3)
    base = Camera.look_at(eye, look, up=rng.normal(size=3), width=width, height=height,
                          fov_x_degrees=rng.uniform(40, 80))
    fx = base.fx
    fy = fx * rng.uniform(0.9, 1.1)
    cx = width * rng.uniform(0.4, 0.6)
    cy = height * rng.uniform(0.4, 0.6)
    return Camera(base.world_to_camera, fx, fy, cx, cy, width, height)


def random_gaussians(rng: np.random.Generator, n: int, degree: int, *, centre=(0.0, 0.0, 0.0),
                     radius: float = 2.5, stray: float = 0.1) -> Gaussians:
    """`n` Gaussians in a ball of `radius` about `centre`, a fraction `stray` of them scattered
    five times as wide; sizes about 0.01..0.5 (anisotropic), opacities from nearly 0 to nearly 1,
    unnormalised quaternions, SH coefficients for `degree` (colours mostly in [0, 1])."""
    centre = np.asarray(centre, np.float64)
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    spread = np.where(rng.random(n) < stray, 5 * radius, radius)
    means = centre + direction * (spread * rng.random(n) ** (1 / 3))[:, None]
    log_scales = (rng.uniform(np.log(0.015), np.log(0.35), size=(n, 1))
                  + rng.normal(scale=0.5, size=(n, 3)))
    quats = rng.normal(size=(n, 4)) * rng.uniform(0.2, 3.0, size=(n, 1))
    opacity_logits = rng.normal(scale=2.5, size=n)
    k = sh_count(degree)
    sh = rng.normal(scale=0.25, size=(n, k, 3))
    sh[:, 0] = rng.normal(scale=0.6, size=(n, 3))
    return Gaussians(means, log_scales, quats, opacity_logits, sh)


def random_scene(rng: np.random.Generator, n: int, width: int, height: int,
                 degree: int) -> tuple[Gaussians, Camera]:
    """Gaussians about the origin seen by a camera 6 units away (depths mostly 3.5..8.5)."""
    return random_gaussians(rng, n, degree), random_camera(rng, width, height)


def random_mesh_layer(rng: np.random.Generator, width: int, height: int, *,
                      depth_range=(3.5, 8.5)) -> tuple[np.ndarray, np.ndarray]:
    """A premultiplied (H, W, 4) mesh colour and (H, W) planar depth, float32: a third of the
    pixels empty (alpha 0, depth inf), a third opaque, a third partly covered, with depths spread
    over `depth_range` (among the Gaussians)."""
    kind = rng.integers(0, 3, size=(height, width))
    alpha = np.where(kind == 0, 0.0, np.where(kind == 1, 1.0, rng.uniform(0.05, 0.95, (height, width))))
    rgba = np.empty((height, width, 4))
    rgba[..., :3] = rng.random((height, width, 3)) * alpha[..., None]
    rgba[..., 3] = alpha
    depth = np.where(kind == 0, np.inf, rng.uniform(*depth_range, size=(height, width)))
    return rgba.astype(np.float32), depth.astype(np.float32)


def fast_random_gaussians(rng: np.random.Generator, n: int, degree: int = 1) -> Gaussians:
    """Many Gaussians quickly (float32 draws), for native-only tests that need no reference."""
    f = np.float32
    means = rng.standard_normal((n, 3), dtype=f) * f(1.5)
    log_scales = rng.uniform(np.log(0.005), np.log(0.2), size=(n, 1)).astype(f) \
        + rng.standard_normal((n, 3), dtype=f) * f(0.4)
    quats = rng.standard_normal((n, 4), dtype=f)
    opacity_logits = rng.standard_normal(n, dtype=f) * f(2)
    sh = rng.standard_normal((n, sh_count(degree), 3), dtype=f) * f(0.3)
    return Gaussians(means, log_scales, quats, opacity_logits, sh)


def playbot_camera() -> Camera:
    """A fixed 160x120 view of ../shared/data/splats/playbot_125k_sh2.ply (its frame is y-down)."""
    return Camera.look_at((0.0, -1.2, -2.6), (0.0, -0.45, 0.0), (0, -1, 0), width=160, height=120,
                          fov_x_degrees=50)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b) ** 2))
    return math.inf if mse == 0 else -10.0 * math.log10(mse)


def sphere_gaussians(radius: float = 1.0, count: int = 3000, sigma: float = 0.05,
                     centre=(0.0, 0.0, 0.0)) -> Gaussians:
    """Isotropic, nearly opaque Gaussians on a sphere: red on top (z > 0), blue below."""
    i = np.arange(count) + 0.5
    z = 1 - 2 * i / count
    r = np.sqrt(1 - z * z)
    phi = np.pi * (3 - np.sqrt(5)) * np.arange(count)
    dirs = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    colour = np.where(dirs[:, 2:3] > 0, [0.9, 0.2, 0.1], [0.1, 0.2, 0.9])
    sh = ((colour - 0.5) / SH_C0)[:, None, :]
    return Gaussians(np.asarray(centre) + radius * dirs, np.full((count, 3), np.log(sigma)),
                     np.tile([1.0, 0, 0, 0], (count, 1)), np.full(count, 4.0), sh)
