"""The renderer's Python API: `render()` and `project()` over the native module `splatcore`.

Semantics are the reference 3DGS rasterizer's (docs/conventions.md, "Rendering semantics"); the float64
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

from dataclasses import dataclass, field
from typing import Iterator

import numpy as np

from .. import native
from ..cameras import Camera
from ..gaussians import Gaussians


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


def project(gaussians: Gaussians, camera: Camera, *, antialiased: bool = False, near: float = 0.01,
            sh_degree: int | None = None, threads: int = 0) -> Projection:
    """Project every Gaussian into `camera` (the renderer's first stage, exposed for tests)."""
    native.camera_args(camera)  # the camera checked before anything is allocated
    n = len(gaussians)
    out = Projection(np.zeros((n, 2), np.float32), np.zeros((n, 3), np.float32),
                     np.zeros(n, np.float32), np.zeros(n, np.float32),
                     np.zeros((n, 3), np.float32), np.zeros(n, np.uint8))
    native.project(gaussians, camera, out.xy, out.conic, out.depth, out.opacity, out.rgb,
                   out.valid, sh_degree=sh_degree, near=near, antialiased=antialiased,
                   threads=threads)
    out.valid = out.valid.view(bool)
    return out


def render(gaussians: Gaussians, camera: Camera, *, background: np.ndarray | None = None,
           mesh_rgba: np.ndarray | None = None, mesh_depth: np.ndarray | None = None,
           antialiased: bool = False, near: float = 0.01, sh_degree: int | None = None,
           threads: int = 0, exhaustive: bool = False,
           out: RenderResult | None = None) -> RenderResult:
    """Render `gaussians` seen by `camera`, optionally composed with a mesh layer.

    background: RGB (3,) behind everything, or None for black.
    mesh_rgba, mesh_depth: (H, W, 4) premultiplied colour and (H, W) planar depth of what Blender
        rendered; both or neither. Pixels with no mesh have alpha 0 (their depth is then unused).
    sh_degree: use at most this many SH bands (None: all the Gaussians have).
    threads: worker threads, 0 for all cores; the image is identical for any count.
    exhaustive: evaluate every Gaussian over the whole bounding span of each of its tiles, not only
        the half rows its alpha >= 1/255 ellipse reaches: the slow twin of that optimisation, for
        tests and benchmarks; the image is the same bit for bit.
    out: a RenderResult of this size to render into (its arrays are overwritten and returned),
        or None for new images. New images come from the memory the renderer keeps between
        frames (`kept_image`): fresh memory's page faults cost a 3840x2160 frame as much as its
        composite, 7680x4320 more.
    """
    _, _, width, height = native.camera_args(camera)
    if (mesh_rgba is None) != (mesh_depth is None):
        raise ValueError("mesh_rgba and mesh_depth must be given together")
    background = native.background_arg(background)
    if mesh_rgba is not None:
        mesh_rgba = native.float_image("mesh_rgba", mesh_rgba, (height, width, 4))
        mesh_depth = native.float_image("mesh_depth", mesh_depth, (height, width))
    if out is None:
        out = RenderResult(kept_image((height, width, 3)), kept_image((height, width)),
                           kept_image((height, width)))
    out.stats = native.render(gaussians, camera, background, mesh_rgba, mesh_depth, out.rgb,
                              out.alpha, out.depth, sh_degree=sh_degree, near=near,
                              antialiased=antialiased, threads=threads, exhaustive=exhaustive)
    return out


def kept_image(shape: tuple[int, ...]) -> np.ndarray:
    """An uninitialised float32 image of `shape` in memory the renderer keeps between frames
    (native/src/buffers.c): once it and every view of it are gone, the memory goes back to be
    kept, and the next frame's images are written into the same pages instead of fresh ones
    faulted in and zeroed by the system. `release_buffers()` frees what is kept."""
    count = int(np.prod(shape))
    return np.frombuffer(native.image_memory(4 * count), np.float32, count).reshape(shape)


def viewport_image(result: RenderResult, projection, *,
                   threads: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A render as a viewport draws it: premultiplied RGBA (H, W, 4) float32 and the depth-buffer
    value of each pixel's planar depth under the 4x4 OpenGL `projection` (default depth range
    [0, 1]; 1 where nothing was hit), (H, W) float32, both rows bottom to top (a texture's
    order). New arrays in kept memory (`kept_image`), filled natively in one parallel pass
    (tests/reference.py's `window_depth` is the float64 formula)."""
    p = np.asarray(projection, np.float64)
    height, width = result.alpha.shape
    rgba, depth = kept_image((height, width, 4)), kept_image((height, width))
    native.viewport_image(result.rgb, result.alpha, result.depth,
                          np.array([p[2, 2], p[2, 3], p[3, 2], p[3, 3]], np.float64), rgba, depth,
                          threads=threads)
    return rgba, depth


def release_buffers() -> None:
    """Give the working buffers renders keep for the next frame back to the system (after a
    render job: a viewport draw or the next F12 allocates them again)."""
    native.release_buffers()


def seen_by_any(gaussians: Gaussians, cameras, *, antialiased: bool = False,
                near: float = 0.01, threads: int = 0) -> np.ndarray:
    """(N,) bool: True where some camera of `cameras` renders the Gaussian. The others are
    culled in every one of them (behind the near plane, or with their whole footprint, out to
    where their alpha falls below the renderer's 1/255, outside the image, or too transparent
    to show at all): leaving them out changes no render from those cameras."""
    n = len(gaussians)
    seen = np.zeros(n, bool)
    for camera in cameras:
        p = project(gaussians, camera, antialiased=antialiased, near=near, sh_degree=0,
                    threads=threads)
        visible = p.valid & (p.opacity * 255.0 > 1.0)
        a, b, c = p.conic[:, 0].astype(np.float64), p.conic[:, 1], p.conic[:, 2]
        det = a * c - b * b
        with np.errstate(divide="ignore", invalid="ignore"):
            # The ellipse where alpha >= 1/255: q <= 2 ln(255 opacity), q the conic's form; its
            # bounding box's half sizes are sqrt(r2 cov_xx), sqrt(r2 cov_yy), cov = inverse conic.
            r2 = 2.0 * np.log(np.maximum(p.opacity * 255.0, 1.0))
            half_x = np.sqrt(np.maximum(r2 * c / det, 0.0)) + 1.0
            half_y = np.sqrt(np.maximum(r2 * a / det, 0.0)) + 1.0
        x, y = p.xy[:, 0], p.xy[:, 1]
        inside = ((x + half_x >= 0) & (x - half_x <= camera.width)
                  & (y + half_y >= 0) & (y - half_y <= camera.height))
        seen |= visible & (inside | ~np.isfinite(half_x) | ~np.isfinite(half_y))
    return seen
