"""Surfaces from splats: cameras around an object, TSDF fusion of rendered depth, surface nets.

The pipeline (see docs/guide/meshes.md):

1. `fibonacci_cameras` puts cameras on a sphere around the splats (or the caller brings the
   COLMAP cameras the splats were trained from); `render_views` renders each with the native
   renderer: expected planar depth and alpha.
2. `fuse_tsdf` fuses those depth maps into a truncated signed distance volume sampled at grid
   points (positive outside, negative inside, in units of the truncation distance):
     - a grid point that projects onto a pixel with alpha >= `min_alpha` and a finite depth
       gets `sdf = depth - z` (z: its planar camera depth), clamped to [-1, 1] after dividing
       by the truncation, weighted by the pixel's alpha, unless it lies more than the
       truncation behind the surface (then the view says nothing about it but "occluded");
     - a grid point that projects onto a pixel the view sees through (alpha < `min_alpha`) is
       free space: +1, weighted by `1 - alpha` (space carving);
     - points outside every view's frustum get no weight.
   Points that no view updated (weight 0) are outside unless some view saw them hidden behind
   the surface: those are inside. This closes the volume behind the truncation band, so the
   extracted surface is one closed shell rather than a skin with an inner wall.
3. `extract_surface` runs **surface nets** on the sign of the volume: one vertex per cell whose
   eight corners do not all agree, at the mean of its edges' zero crossings; one quad per
   sign-changing grid edge joining the four cells around it, oriented so that its normal points
   from inside to outside, split into two triangles. The volume is padded with an outside layer,
   so every sign-changing edge has its four cells and the mesh is closed (watertight: every edge
   has two triangles, except at ambiguous saddle faces of the grid, which are rare on smooth
   surfaces). Vectorised numpy, no lookup tables.

`zbuffer_depth` is an exact numpy triangle rasteriser for planar depth (to measure a mesh against
the splats' own depth). Everything here is numpy only; decimation is Blender's (its Decimate
modifier), see `addon/blender/mesh_convert.py`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from ..cameras import Camera
from ..gaussians import Gaussians


# -- cameras -------------------------------------------------------------------------------------

def fibonacci_cameras(centre, radius: float, count: int, width: int, height: int,
                      fov: float = 50.0) -> list[Camera]:
    """`count` cameras evenly spread on a sphere of `radius` around `centre` (a Fibonacci
    lattice), each looking at the centre, `fov` the horizontal field of view in degrees."""
    if count < 1:
        raise ValueError(f"count must be at least 1, got {count}")
    if not radius > 0:
        raise ValueError(f"radius must be positive, got {radius}")
    centre = np.asarray(centre, np.float64)
    golden = np.pi * (3.0 - np.sqrt(5.0))
    cameras = []
    for i in range(count):
        z = 1.0 - 2.0 * (i + 0.5) / count
        r = np.sqrt(max(0.0, 1.0 - z * z))
        phi = golden * i
        direction = np.array([r * np.cos(phi), r * np.sin(phi), z])
        up = (0.0, 0.0, 1.0) if abs(z) < 0.99 else (0.0, 1.0, 0.0)
        cameras.append(Camera.look_at(centre + radius * direction, centre, up, width=width,
                                      height=height, fov_x_degrees=fov))
    return cameras


def splat_bounds(gaussians: Gaussians, *, percentile: float = 0.5,
                 margin: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """An axis-aligned box holding the splats: the `percentile`..`100 - percentile` range of
    the centres (drops stray floaters), grown by `margin` of its size plus the median
    Gaussian's 3 sigma on every side."""
    if len(gaussians) == 0:
        raise ValueError("no splats to bound")
    means = gaussians.means.astype(np.float64)
    lo = np.percentile(means, percentile, axis=0)
    hi = np.percentile(means, 100 - percentile, axis=0)
    sigma = float(np.exp(np.median(gaussians.log_scales.max(axis=1))))
    pad = margin * float((hi - lo).max()) + 3.0 * sigma
    pad = max(pad, 1e-6)
    return lo - pad, hi + pad


def framing_radius(bounds, fov: float) -> float:
    """Distance from the box centre at which a camera with horizontal field of view `fov` (and
    a square image) sees the whole box."""
    lo, hi = (np.asarray(b, np.float64) for b in bounds)
    half = 0.5 * float(np.linalg.norm(hi - lo))
    return half / np.sin(np.radians(fov) / 2) * 1.05


@dataclass
class View:
    camera: Camera
    rgb: np.ndarray    # (H, W, 3) premultiplied
    alpha: np.ndarray  # (H, W)
    depth: np.ndarray  # (H, W) planar, inf where nothing


def render_views(gaussians: Gaussians, cameras: Sequence[Camera], *, antialiased: bool = False,
                 threads: int = 0, progress: Callable[[int, int], None] | None = None,
                 cancel: Callable[[], bool] | None = None) -> list[View]:
    """Native renders (colour, alpha, depth) of `gaussians` from every camera."""
    from ..render.renderer import render

    views = []
    for i, camera in enumerate(cameras):
        if cancel is not None and cancel():
            raise Cancelled()
        rgb, alpha, depth = render(gaussians, camera, antialiased=antialiased, threads=threads)
        views.append(View(camera, rgb, alpha, depth))
        if progress is not None:
            progress(i + 1, len(cameras))
    return views


def project_points(camera: Camera, points: np.ndarray, near: float
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Planar depth z and pixel coordinates (u, v) of world-space `points` (N, 3) seen by
    `camera`, and which points are in view: in front of `near` and inside the frame."""
    r, t = camera.world_to_camera[:3, :3], camera.world_to_camera[:3, 3]
    c = points @ r.T + t
    z = c[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = camera.fx * c[:, 0] / z + camera.cx
        v = camera.fy * c[:, 1] / z + camera.cy
    in_view = (z > near) & (u >= 0) & (u < camera.width) & (v >= 0) & (v < camera.height)
    return z, u, v, in_view


class Cancelled(Exception):
    """Raised between stages or views when the caller's `cancel()` says so."""


# -- TSDF fusion ---------------------------------------------------------------------------------

@dataclass
class Grid:
    """Grid points `origin + voxel * (i, j, k)` for i < shape[0] etc."""

    origin: np.ndarray
    voxel: float
    shape: tuple[int, int, int]

    @classmethod
    def from_bounds(cls, bounds, resolution: int) -> "Grid":
        """`resolution` cells along the box's longest side, cubic voxels."""
        if resolution < 2:
            raise ValueError(f"resolution must be at least 2, got {resolution}")
        lo, hi = (np.asarray(b, np.float64) for b in bounds)
        if lo.shape != (3,) or hi.shape != (3,) or not (hi > lo).all():
            raise ValueError(f"bounds must be (min xyz, max xyz) with max > min, got {lo}, {hi}")
        voxel = float((hi - lo).max()) / resolution
        counts = np.ceil((hi - lo) / voxel - 1e-9).astype(int) + 1
        return cls(lo, voxel, tuple(int(c) for c in counts))

    def points(self) -> np.ndarray:
        """(nx*ny*nz, 3) world positions in C order."""
        axes = [self.origin[a] + self.voxel * np.arange(self.shape[a]) for a in range(3)]
        gx, gy, gz = np.meshgrid(*axes, indexing="ij")
        return np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=1)


@dataclass
class TSDF:
    grid: Grid
    tsdf: np.ndarray      # (nx, ny, nz) float32 in [-1, 1], positive outside
    weight: np.ndarray    # (nx, ny, nz) float32
    occluded: np.ndarray  # (nx, ny, nz) bool: some view saw the point hidden behind the surface
    truncation: float

    def inside(self) -> np.ndarray:
        """Inside = known and negative, or unknown but seen hidden behind the surface."""
        return np.where(self.weight > 0, self.tsdf < 0, self.occluded)

    def signed(self) -> np.ndarray:
        """The field surface nets contours: the tsdf where known, -1/+1 for unknown points."""
        return np.where(self.weight > 0, self.tsdf,
                        np.where(self.occluded, -1.0, 1.0)).astype(np.float32)


def fuse_tsdf(depth_maps: Sequence[np.ndarray], alpha_maps: Sequence[np.ndarray],
              cameras: Sequence[Camera], bounds, resolution: int,
              truncation: float | None = None, *, min_alpha: float = 0.5, near: float = 0.01,
              chunk: int = 1 << 18, cancel: Callable[[], bool] | None = None,
              progress: Callable[[int, int], None] | None = None) -> TSDF:
    """Fuse planar depth maps into a truncated signed distance volume (see the module notes).

    depth_maps, alpha_maps: (H, W) per camera (the native renderer's expected depth and alpha).
    bounds: (min xyz, max xyz); resolution: cells along the longest side.
    truncation: in world units, default 3 voxels.
    """
    if not (len(depth_maps) == len(alpha_maps) == len(cameras)):
        raise ValueError("need one depth map and one alpha map per camera")
    grid = Grid.from_bounds(bounds, resolution)
    if truncation is None:
        truncation = 3.0 * grid.voxel
    if not truncation > 0:
        raise ValueError(f"truncation must be positive, got {truncation}")
    points = grid.points()
    n = len(points)
    sum_w = np.zeros(n, np.float64)
    sum_wd = np.zeros(n, np.float64)
    occluded = np.zeros(n, bool)
    for v, (depth, alpha, cam) in enumerate(zip(depth_maps, alpha_maps, cameras)):
        if cancel is not None and cancel():
            raise Cancelled()
        depth = np.asarray(depth, np.float32)
        alpha = np.asarray(alpha, np.float32)
        if depth.shape != (cam.height, cam.width) or alpha.shape != depth.shape:
            raise ValueError(f"view {v}: depth and alpha must be {(cam.height, cam.width)}")
        for start in range(0, n, chunk):
            z, u, vv, ok = project_points(cam, points[start:start + chunk], near)
            idx = np.nonzero(ok)[0]
            if not len(idx):
                continue
            px = u[idx].astype(np.int64)
            py = vv[idx].astype(np.int64)
            a = alpha[py, px].astype(np.float64)
            d = depth[py, px].astype(np.float64)
            zi = z[idx]
            hit = (a >= min_alpha) & np.isfinite(d)
            sdf = (d - zi) / truncation
            band = hit & (sdf > -1.0)
            behind = hit & ~band
            free = ~hit
            g = start + idx
            gb = g[band]
            sum_w[gb] += a[band]
            sum_wd[gb] += a[band] * np.minimum(sdf[band], 1.0)
            gf = g[free]
            wf = 1.0 - a[free]
            sum_w[gf] += wf
            sum_wd[gf] += wf
            occluded[g[behind]] = True
        if progress is not None:
            progress(v + 1, len(cameras))
    with np.errstate(invalid="ignore", divide="ignore"):
        value = np.where(sum_w > 0, sum_wd / np.maximum(sum_w, 1e-30), 1.0)
    shape = grid.shape
    return TSDF(grid, value.reshape(shape).astype(np.float32),
                sum_w.reshape(shape).astype(np.float32), occluded.reshape(shape),
                float(truncation))


# -- surface nets --------------------------------------------------------------------------------

def surface_nets(field_: np.ndarray, origin, voxel: float,
                 inside: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Triangles of the zero level set of `field_` (grid values, negative inside).

    `inside` (bool, same shape) overrides the sign test `field_ < 0` when given. The volume is
    padded with an outside layer first, so the result is closed. Returns vertices (V, 3)
    float64 and faces (F, 3) int64 with counter-clockwise (outward) winding.
    """
    f = np.asarray(field_, np.float64)
    if f.ndim != 3:
        raise ValueError(f"field must be 3D, got shape {f.shape}")
    ins = (f < 0) if inside is None else np.asarray(inside, bool)
    # Values consistent with the sign (a crossing must lie between the two corners).
    f = np.where(ins, np.minimum(f, -1e-6), np.maximum(f, 1e-6))
    f = np.pad(f, 1, constant_values=1.0)
    ins = np.pad(ins, 1, constant_values=False)
    ins = resolve_saddles(ins)
    f = np.where(ins, np.minimum(f, -1e-6), f)
    origin = np.asarray(origin, np.float64) - voxel
    shape = np.array(f.shape)
    cells = shape - 1
    ncells = int(np.prod(cells))
    acc = np.zeros((ncells, 3), np.float64)
    cnt = np.zeros(ncells, np.int64)
    quads = []
    for axis in range(3):
        a0 = [slice(None)] * 3
        a1 = [slice(None)] * 3
        a0[axis] = slice(0, -1)
        a1[axis] = slice(1, None)
        i0, i1 = ins[tuple(a0)], ins[tuple(a1)]
        change = i0 != i1
        idx = np.argwhere(change)  # (E, 3) lower corner of each sign-changing edge
        if not len(idx):
            continue
        f0 = f[tuple(a0)][change]
        f1 = f[tuple(a1)][change]
        t = f0 / (f0 - f1)
        pos = idx.astype(np.float64)
        pos[:, axis] += t
        # The four cells around the edge: offsets -1/0 along the two other axes.
        o1, o2 = (axis + 1) % 3, (axis + 2) % 3  # right-handed with `axis`
        around = []
        for d1, d2 in ((-1, -1), (0, -1), (0, 0), (-1, 0)):
            c = idx.copy()
            c[:, o1] += d1
            c[:, o2] += d2
            around.append(c)
        for c in around:
            valid = (c >= 0).all(axis=1) & (c < cells).all(axis=1)
            flat = np.ravel_multi_index(c[valid].T, cells)
            np.add.at(acc, flat, pos[valid])
            np.add.at(cnt, flat, 1)
        # Padding guarantees every sign change is interior: all four cells exist.
        flat4 = np.stack([np.ravel_multi_index(c.T, cells) for c in around], axis=1)
        # (o1, o2, axis) is a cyclic (right-handed) order, so the quad's normal is +axis;
        # it must point from inside to outside.
        outward_positive = i0[change]
        flat4 = np.where(outward_positive[:, None], flat4, flat4[:, ::-1])
        quads.append(flat4)
    if not quads:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    quads = np.concatenate(quads)
    used = np.nonzero(cnt)[0]
    remap = np.full(ncells, -1, np.int64)
    remap[used] = np.arange(len(used))
    vertices = origin + voxel * (acc[used] / cnt[used, None])
    q = remap[quads]
    # Split each quad along its shorter diagonal.
    d02 = np.linalg.norm(vertices[q[:, 0]] - vertices[q[:, 2]], axis=1)
    d13 = np.linalg.norm(vertices[q[:, 1]] - vertices[q[:, 3]], axis=1)
    use02 = d02 <= d13
    tri_a = np.where(use02[:, None], q[:, [0, 1, 2]], q[:, [0, 1, 3]])
    tri_b = np.where(use02[:, None], q[:, [0, 2, 3]], q[:, [1, 2, 3]])
    faces = np.concatenate([tri_a, tri_b])
    return vertices, faces


def resolve_saddles(inside: np.ndarray, rounds: int = 16) -> np.ndarray:
    """Grow the inside at ambiguous grid faces (two inside corners on one diagonal, two outside
    on the other) until there are none: there surface nets would join four quads on one edge.
    Joining the two inside corners (as marching cubes' "connect inside" rule does) keeps every
    edge shared by exactly two triangles."""
    ins = np.array(inside, bool)
    for _ in range(rounds):
        changed = False
        for p, q in ((0, 1), (1, 2), (0, 2)):
            def part(dp, dq):
                sl = [slice(None)] * 3
                sl[p] = slice(dp, ins.shape[p] - 1 + dp)
                sl[q] = slice(dq, ins.shape[q] - 1 + dq)
                return tuple(sl)
            c00, c10, c01, c11 = (ins[part(a, b)] for a, b in ((0, 0), (1, 0), (0, 1), (1, 1)))
            amb = (c00 == c11) & (c10 == c01) & (c00 != c10)
            if not amb.any():
                continue
            changed = True
            grow_main = amb & ~c00  # the 00-11 diagonal is outside: make it inside
            grow_anti = amb & c00
            ins[part(0, 0)] |= grow_main
            ins[part(1, 1)] |= grow_main
            ins[part(1, 0)] |= grow_anti
            ins[part(0, 1)] |= grow_anti
        if not changed:
            break
    return ins


def extract_surface(volume: TSDF) -> tuple[np.ndarray, np.ndarray]:
    """Surface nets on a fused volume (unknown points: see `TSDF.inside`)."""
    return surface_nets(volume.signed(), volume.grid.origin, volume.grid.voxel,
                        inside=volume.inside())


def largest_components(vertices: np.ndarray, faces: np.ndarray, *,
                       min_fraction: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Drop connected pieces with fewer than `min_fraction` of the faces (floaters' blobs)."""
    if not len(faces):
        return vertices, faces
    n = len(vertices)
    # Label propagation over edges (vectorised min-label iteration).
    label = np.arange(n)
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    for _ in range(10000):
        m = np.minimum(label[edges[:, 0]], label[edges[:, 1]])
        new = label.copy()
        np.minimum.at(new, edges[:, 0], m)
        np.minimum.at(new, edges[:, 1], m)
        new = new[new]  # pointer jumping
        if np.array_equal(new, label):
            break
        label = new
    face_label = label[faces[:, 0]]
    ids, counts = np.unique(face_label, return_counts=True)
    keep_ids = ids[counts >= min_fraction * len(faces)]
    keep = np.isin(face_label, keep_ids)
    faces = faces[keep]
    used = np.unique(faces)
    remap = np.full(n, -1, np.int64)
    remap[used] = np.arange(len(used))
    return vertices[used], remap[faces]


# -- mesh checks and depth -----------------------------------------------------------------------

def edge_face_counts(faces: np.ndarray) -> np.ndarray:
    """How many faces share each undirected edge."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.sort(e, axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return counts


def is_watertight(faces: np.ndarray) -> bool:
    return len(faces) > 0 and bool((edge_face_counts(faces) == 2).all())


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Positive for a closed mesh with outward (counter-clockwise) winding."""
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    fn = np.cross(b - a, c - a)  # area weighted
    vn = np.zeros_like(vertices, dtype=np.float64)
    for i in range(3):
        np.add.at(vn, faces[:, i], fn)
    norm = np.linalg.norm(vn, axis=1, keepdims=True)
    return vn / np.maximum(norm, 1e-30)


def raster_candidates(x0, x1, y0, y1, limit: int):
    """Yield (triangle ids, px, py) of every pixel in each triangle's bounding box (columns
    x0..x1, rows y0..y1, inclusive), in chunks of about `limit` pixels."""
    w = np.maximum(x1 - x0 + 1, 0)
    h = np.maximum(y1 - y0 + 1, 0)
    counts = (w * h).astype(np.int64)
    tris = np.nonzero(counts)[0]
    if not len(tris):
        return
    csum = np.cumsum(counts[tris])
    start = 0
    while start < len(tris):
        base = csum[start - 1] if start else 0
        end = int(np.searchsorted(csum, base + limit, side="right"))
        end = max(end, start + 1)
        sel = tris[start:end]
        c = counts[sel]
        tid = np.repeat(sel, c)
        offs = np.arange(int(c.sum())) - np.repeat(np.cumsum(c) - c, c)
        px = x0[tid] + offs % w[tid]
        py = y0[tid] + offs // w[tid]
        yield tid, px, py
        start = end


def barycentric(xs: np.ndarray, ys: np.ndarray, x: np.ndarray, y: np.ndarray, eps: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Barycentric weights (l0, l1, l2) of the points (x, y) in the triangles whose corners are
    (xs[:, k], ys[:, k]), and whether each point is inside (every weight >= eps; never in a
    degenerate triangle)."""
    det = ((ys[:, 1] - ys[:, 2]) * (xs[:, 0] - xs[:, 2])
           + (xs[:, 2] - xs[:, 1]) * (ys[:, 0] - ys[:, 2]))
    with np.errstate(divide="ignore", invalid="ignore"):
        l0 = ((ys[:, 1] - ys[:, 2]) * (x - xs[:, 2]) + (xs[:, 2] - xs[:, 1]) * (y - ys[:, 2])) / det
        l1 = ((ys[:, 2] - ys[:, 0]) * (x - xs[:, 2]) + (xs[:, 0] - xs[:, 2]) * (y - ys[:, 2])) / det
    l2 = 1.0 - l0 - l1
    inside = (l0 >= eps) & (l1 >= eps) & (l2 >= eps) & np.isfinite(l0) & (det != 0)
    return l0, l1, l2, inside


def zbuffer_depth(vertices: np.ndarray, faces: np.ndarray, camera: Camera, *,
                  near: float = 0.01, chunk: int = 1 << 21) -> np.ndarray:
    """Planar depth of a triangle mesh seen by `camera` (pixel centres, nearest surface, `inf`
    where nothing): an exact rasteriser (perspective-correct: 1/z is linear in screen space).
    Triangles crossing the near plane are skipped."""
    h, w = camera.height, camera.width
    out = np.full(h * w, np.inf, np.float64)
    if not len(faces):
        return out.reshape(h, w).astype(np.float32)
    r, t = camera.world_to_camera[:3, :3], camera.world_to_camera[:3, 3]
    c = np.asarray(vertices, np.float64) @ r.T + t
    z = c[:, 2]
    zs = np.where(z > near, z, np.nan)
    u = camera.fx * c[:, 0] / zs + camera.cx
    v = camera.fy * c[:, 1] / zs + camera.cy
    fz = z[faces]
    ok = (fz > near).all(axis=1)
    f = faces[ok]
    fu, fv, fzz = u[f], v[f], z[f]
    x0 = np.clip(np.ceil(fu.min(axis=1) - 0.5), 0, w).astype(np.int64)
    x1 = np.clip(np.floor(fu.max(axis=1) - 0.5), -1, w - 1).astype(np.int64)
    y0 = np.clip(np.ceil(fv.min(axis=1) - 0.5), 0, h).astype(np.int64)
    y1 = np.clip(np.floor(fv.max(axis=1) - 0.5), -1, h - 1).astype(np.int64)
    for tid, px, py in raster_candidates(x0, x1, y0, y1, chunk):
        cc = fzz[tid]
        l0, l1, l2, inside = barycentric(fu[tid], fv[tid], px + 0.5, py + 0.5, eps=-1e-9)
        inv_z = l0 / cc[:, 0] + l1 / cc[:, 1] + l2 / cc[:, 2]
        depth = 1.0 / inv_z
        sel = inside & (depth > 0)
        np.minimum.at(out, py[sel] * w + px[sel], depth[sel])
    return out.reshape(h, w).astype(np.float32)


# -- the whole extraction ------------------------------------------------------------------------

@dataclass
class SurfaceResult:
    vertices: np.ndarray
    faces: np.ndarray
    volume: TSDF
    bounds: tuple[np.ndarray, np.ndarray]
    views: list[View]
    seconds: dict[str, float] = field(default_factory=dict)


def splats_to_surface(gaussians: Gaussians, *, resolution: int = 128,
                      cameras: Sequence[Camera] | None = None, view_count: int = 48,
                      view_size: int = 192, fov: float = 50.0, bounds=None,
                      antialiased: bool = False, threads: int = 0, min_component: float = 0.01,
                      progress: Callable[[str, float], None] | None = None,
                      cancel: Callable[[], bool] | None = None) -> SurfaceResult:
    """Render depth from `cameras` (default: `view_count` Fibonacci cameras framing the splats),
    fuse, extract, and drop pieces smaller than `min_component` of the faces."""
    seconds = {}
    start = time.perf_counter()
    if bounds is None:
        bounds = splat_bounds(gaussians)
    bounds = tuple(np.asarray(b, np.float64) for b in bounds)
    if cameras is None:
        centre = 0.5 * (bounds[0] + bounds[1])
        cameras = fibonacci_cameras(centre, framing_radius(bounds, fov), view_count,
                                    view_size, view_size, fov)
    report = (lambda stage, f: progress(stage, f)) if progress else None
    views = render_views(gaussians, cameras, antialiased=antialiased, threads=threads,
                         cancel=cancel,
                         progress=(lambda i, n: report("render", i / n)) if report else None)
    seconds["render"] = time.perf_counter() - start
    start = time.perf_counter()
    volume = fuse_tsdf([v.depth for v in views], [v.alpha for v in views],
                       [v.camera for v in views], bounds, resolution, cancel=cancel,
                       progress=(lambda i, n: report("fuse", i / n)) if report else None)
    seconds["fuse"] = time.perf_counter() - start
    if cancel is not None and cancel():
        raise Cancelled()
    start = time.perf_counter()
    vertices, faces = extract_surface(volume)
    if min_component > 0:
        vertices, faces = largest_components(vertices, faces, min_fraction=min_component)
    seconds["extract"] = time.perf_counter() - start
    return SurfaceResult(vertices, faces, volume, bounds, views, seconds)
