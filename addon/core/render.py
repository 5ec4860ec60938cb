"""The renderer's Python API: `render()` and `project()` over the native module `splatcore`.

Semantics are the reference 3DGS rasterizer's (DESIGN.md, "Rendering semantics"); the float64
NumPy twin in `tests/reference.py` is what the native code is held against.

Layers, front to back, per pixel:
  1. the Gaussians in front of the mesh (view-space depth of the mean < `mesh_depth`), in depth
     order, with the reference's 1/255 alpha skip and 1e-4 transmittance stop;
  2. the mesh pixel (`mesh_rgba`, premultiplied) weighted by the transmittance left;
  3. the Gaussians behind it, by the same rules;
  4. `background`, an RGB colour, weighted by the transmittance left.

Outputs: `rgb` premultiplied (the background included), `alpha = 1 - T` (coverage by splats and
mesh; the background does not count), `depth` the expected planar depth `sum(w z) / sum(w)` over
the Gaussians and the mesh layer (weights `w = alpha_i T_i`), `inf` where nothing was hit.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Iterator

import numpy as np

from .cameras import Camera
from .gaussians import Gaussians

# Images beyond these are refused before anything is allocated.
MAX_SIDE = 32768
MAX_PIXELS = 1 << 27


def _splatcore():
    try:
        import splatcore
    except ImportError as error:  # pragma: no cover - a broken install, not a code path
        raise ImportError(
            "the native module 'splatcore' is not installed; run scripts/bootstrap.sh "
            "(or pip install ./native)") from error
    return splatcore


@dataclass
class Projection:
    """Per-Gaussian screen-space data; rows where `valid` is False are zero."""

    xy: np.ndarray        # (N, 2) projected mean in pixels
    conic: np.ndarray     # (N, 3) A, B, C: inverse of the dilated 2D covariance [[A, B], [B, C]]
    depth: np.ndarray     # (N,)   view-space z of the mean
    opacity: np.ndarray   # (N,)   sigmoid(logit), times the antialiasing compensation if on
    rgb: np.ndarray       # (N, 3) SH colour + 0.5, clamped at 0
    valid: np.ndarray     # (N,)   in front of the near plane with a finite, positive-definite footprint


@dataclass
class RenderResult:
    """`rgb, alpha, depth = render(...)` unpacks the images; `stats` holds timings and counts."""

    rgb: np.ndarray
    alpha: np.ndarray
    depth: np.ndarray
    stats: dict[str, float] = field(default_factory=dict)

    def __iter__(self) -> Iterator[np.ndarray]:
        return iter((self.rgb, self.alpha, self.depth))


def _camera_args(camera: Camera) -> tuple[np.ndarray, np.ndarray, int, int]:
    width, height = int(camera.width), int(camera.height)
    if width <= 0 or height <= 0:
        raise ValueError(f"image size must be positive, got {width}x{height}")
    if width > MAX_SIDE or height > MAX_SIDE or width * height > MAX_PIXELS:
        raise ValueError(f"image size {width}x{height} is too large "
                         f"(at most {MAX_SIDE} a side and {MAX_PIXELS} pixels)")
    viewmat = np.ascontiguousarray(camera.world_to_camera, dtype=np.float64)
    intrinsics = np.array([camera.fx, camera.fy, camera.cx, camera.cy], dtype=np.float64)
    return viewmat, intrinsics, width, height


def _sh_degree(gaussians: Gaussians, sh_degree: int | None) -> int:
    if sh_degree is None:
        return gaussians.degree
    if not 0 <= sh_degree <= 3:
        raise ValueError(f"sh_degree must be 0..3 or None, got {sh_degree}")
    return min(sh_degree, gaussians.degree)


def _threads(threads: int) -> int:
    if threads < 0:
        raise ValueError(f"threads must be >= 0 (0 = all cores), got {threads}")
    return threads


def _gaussian_args(gaussians: Gaussians) -> tuple[np.ndarray, ...]:
    if not isinstance(gaussians, Gaussians):
        raise TypeError(f"expected Gaussians, got {type(gaussians).__name__}")
    return (gaussians.means, gaussians.log_scales, gaussians.quats, gaussians.opacity_logits,
            gaussians.sh)


def project(gaussians: Gaussians, camera: Camera, *, antialiased: bool = False, near: float = 0.01,
            sh_degree: int | None = None, threads: int = 0) -> Projection:
    """Project every Gaussian into `camera` (the renderer's first stage, exposed for tests)."""
    viewmat, intrinsics, width, height = _camera_args(camera)
    n = len(gaussians)
    out = Projection(np.zeros((n, 2), np.float32), np.zeros((n, 3), np.float32),
                     np.zeros(n, np.float32), np.zeros(n, np.float32),
                     np.zeros((n, 3), np.float32), np.zeros(n, np.uint8))
    _splatcore().project(*_gaussian_args(gaussians), _sh_degree(gaussians, sh_degree), viewmat,
                         intrinsics, width, height, float(near), bool(antialiased),
                         _threads(threads), out.xy, out.conic, out.depth, out.opacity, out.rgb,
                         out.valid)
    out.valid = out.valid.view(bool)
    return out


def render(gaussians: Gaussians, camera: Camera, *, background: np.ndarray | None = None,
           mesh_rgba: np.ndarray | None = None, mesh_depth: np.ndarray | None = None,
           antialiased: bool = False, near: float = 0.01, sh_degree: int | None = None,
           threads: int = 0) -> RenderResult:
    """Render `gaussians` seen by `camera`, optionally composed with a mesh layer.

    background: RGB (3,) behind everything, or None for black.
    mesh_rgba, mesh_depth: (H, W, 4) premultiplied colour and (H, W) planar depth of what Blender
        rendered; both or neither. Pixels with no mesh have alpha 0 (their depth is then unused).
    sh_degree: use at most this many SH bands (None: all the Gaussians have).
    threads: worker threads, 0 for all cores; the image is identical for any count.
    """
    viewmat, intrinsics, width, height = _camera_args(camera)
    if (mesh_rgba is None) != (mesh_depth is None):
        raise ValueError("mesh_rgba and mesh_depth must be given together")
    if background is not None:
        background = np.ascontiguousarray(background, dtype=np.float32).reshape(-1)
        if background.shape != (3,):
            raise ValueError(f"background must be an RGB triple, got shape {background.shape}")
    if mesh_rgba is not None:
        mesh_rgba = np.ascontiguousarray(mesh_rgba, dtype=np.float32)
        mesh_depth = np.ascontiguousarray(mesh_depth, dtype=np.float32)
        if mesh_rgba.shape != (height, width, 4):
            raise ValueError(f"mesh_rgba must have shape {(height, width, 4)}, got {mesh_rgba.shape}")
        if mesh_depth.shape != (height, width):
            raise ValueError(f"mesh_depth must have shape {(height, width)}, got {mesh_depth.shape}")
    rgb = np.empty((height, width, 3), np.float32)
    alpha = np.empty((height, width), np.float32)
    depth = np.empty((height, width), np.float32)
    stats = _splatcore().render(*_gaussian_args(gaussians), _sh_degree(gaussians, sh_degree),
                                viewmat, intrinsics, width, height, float(near), bool(antialiased),
                                _threads(threads), background, mesh_rgba, mesh_depth,
                                rgb, alpha, depth)
    return RenderResult(rgb, alpha, depth, dict(stats))


def cpu_count() -> int:
    """Cores this process may use (what `threads=0` means)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1
