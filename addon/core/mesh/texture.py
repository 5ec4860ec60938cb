"""Splats -> a mesh's colour texture: UV atlas (xatlas) and a texture projected from splat
renders (what Blender calls texture baking; scene -> splats is `scene_to_splats`).

`unwrap(vertices, faces, texture_size)` charts and packs the mesh with xatlas: it returns
per-corner UVs in [0, 1] for the mesh's own faces (the mesh keeps its vertices, so it stays
watertight; seams live only in the UV layer, as in any Blender mesh).

`rasterise_uv` finds, for each texel centre, the triangle that covers it in UV space and its
barycentric coordinates, hence the texel's world position and (interpolated vertex) normal.

`project_texture` projects views of the splats onto the texels. For each view (native renders:
premultiplied colour, alpha, planar depth), a texel counts when it lies in the image in front of
the near plane, the splats' depth at its pixel agrees with the texel's camera z within `tolerance`
(visibility: nothing of the splats is in front of it) and alpha >= `min_alpha`. Its weight is
`max(0, cos(normal, direction to the camera))^power * alpha`; the colour sampled (bilinear) is
`rgb / alpha`, the splats' own colour without the black background. Weighted colours are
averaged; texels no view saw are filled: `dilate` rounds of the mean of filled neighbours
(fills the seams' gutters), then a push-pull average fill for whatever is left (no holes, no
black lines when mip-mapping).

Texture orientation: row 0 is v = 0 (the bottom of the image, as Blender stores pixels); flip
rows for top-down file formats. Colours are those of the splats, i.e. display sRGB for splats
trained on photos (docs/conventions.md, "Colour"): save the texture as an 8-bit sRGB image so that Blender
converts it to scene linear on load; under the Standard view transform the mesh then shows the
splat colours (exactly so for an emission shader; a lit Principled BSDF adds shading).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from .surface import Cancelled, View, barycentric, project_points, raster_candidates, vertex_normals


def unwrap(vertices: np.ndarray, faces: np.ndarray, texture_size: int = 1024,
           padding: int = 2) -> np.ndarray:
    """Per-corner UVs (F, 3, 2) in [0, 1] from an xatlas atlas packed for `texture_size`."""
    import xatlas

    vertices = np.ascontiguousarray(vertices, np.float32)
    faces32 = np.ascontiguousarray(faces, np.uint32)
    atlas = xatlas.Atlas()
    atlas.add_mesh(vertices, faces32)
    pack = xatlas.PackOptions()
    pack.resolution = int(texture_size)
    pack.padding = int(padding)
    pack.bilinear = True
    pack.blockAlign = False
    atlas.generate(pack_options=pack)
    if atlas.atlas_count != 1:
        # Charts did not fit one atlas at the estimated density: let xatlas choose the density.
        atlas = xatlas.Atlas()
        atlas.add_mesh(vertices, faces32)
        pack = xatlas.PackOptions()
        pack.padding = int(padding)
        atlas.generate(pack_options=pack)
    vmapping, indices, uvs = atlas[0] if hasattr(atlas, "__getitem__") else atlas.get_mesh(0)
    indices = np.asarray(indices, np.int64).reshape(-1, 3)
    uvs = np.asarray(uvs, np.float64)
    if uvs.max() > 1.0 + 1e-6:  # pixel units in some versions
        uvs = uvs / np.array([atlas.width, atlas.height], np.float64)
    vmapping = np.asarray(vmapping, np.int64)
    if len(indices) != len(faces) or not np.array_equal(vmapping[indices], np.asarray(faces)):
        raise RuntimeError("xatlas changed the mesh's faces; cannot map the UVs back")
    return uvs[indices]


@dataclass
class TexelMap:
    """Texels covered by a triangle: their index (row * size + column), world position and
    normal."""

    size: int
    texel: np.ndarray     # (T,) int64
    position: np.ndarray  # (T, 3)
    normal: np.ndarray    # (T, 3) unit


def rasterise_uv(vertices: np.ndarray, faces: np.ndarray, corner_uvs: np.ndarray, size: int,
                 *, chunk: int = 1 << 21) -> TexelMap:
    """Which triangle covers each texel centre `((i + 0.5) / size, (j + 0.5) / size)`."""
    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64)
    normals = vertex_normals(vertices, faces)
    uv = np.asarray(corner_uvs, np.float64) * size - 0.5  # texel-centre coordinates
    fu, fv = uv[..., 0], uv[..., 1]
    x0 = np.clip(np.ceil(fu.min(axis=1)), 0, size).astype(np.int64)
    x1 = np.clip(np.floor(fu.max(axis=1)), -1, size - 1).astype(np.int64)
    y0 = np.clip(np.ceil(fv.min(axis=1)), 0, size).astype(np.int64)
    y1 = np.clip(np.floor(fv.max(axis=1)), -1, size - 1).astype(np.int64)
    owner = np.full(size * size, -1, np.int64)
    bary = np.zeros((size * size, 3), np.float64)
    for tid, px, py in raster_candidates(x0, x1, y0, y1, chunk):
        l0, l1, l2, ok = barycentric(fu[tid], fv[tid], px, py, eps=-1e-6)
        flat = py[ok] * size + px[ok]
        owner[flat] = tid[ok]
        bary[flat] = np.stack([l0[ok], l1[ok], l2[ok]], axis=1)
    texel = np.nonzero(owner >= 0)[0]
    tri = faces[owner[texel]]
    w = np.clip(bary[texel], 0.0, 1.0)
    w /= np.maximum(w.sum(axis=1, keepdims=True), 1e-30)
    position = np.einsum("ti,tij->tj", w, vertices[tri])
    normal = np.einsum("ti,tij->tj", w, normals[tri])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-30)
    return TexelMap(size, texel, position, normal)


def _bilinear(image: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    h, w = image.shape[:2]
    x = np.clip(u - 0.5, 0, w - 1)
    y = np.clip(v - 0.5, 0, h - 1)
    x0 = np.floor(x).astype(np.int64)
    y0 = np.floor(y).astype(np.int64)
    x1 = np.minimum(x0 + 1, w - 1)
    y1 = np.minimum(y0 + 1, h - 1)
    fx = (x - x0)[:, None]
    fy = (y - y0)[:, None]
    return ((image[y0, x0] * (1 - fx) + image[y0, x1] * fx) * (1 - fy)
            + (image[y1, x0] * (1 - fx) + image[y1, x1] * fx) * fy)


def project_views(texels: TexelMap, views: Sequence[View], *, tolerance: float,
                  power: float = 2.0, min_alpha: float = 0.5, near: float = 0.01,
                  cancel: Callable[[], bool] | None = None,
                  progress: Callable[[int, int], None] | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Weighted colour sum (T, 3) and weight sum (T,) of every view's colour at each texel."""
    n = len(texels.texel)
    colour = np.zeros((n, 3), np.float64)
    weight = np.zeros(n, np.float64)
    for i, view in enumerate(views):
        if cancel is not None and cancel():
            raise Cancelled()
        cam = view.camera
        z, u, v, ok = project_points(cam, texels.position, near)
        idx = np.nonzero(ok)[0]
        px, py = u[idx].astype(np.int64), v[idx].astype(np.int64)
        a = view.alpha[py, px].astype(np.float64)
        d = view.depth[py, px].astype(np.float64)
        seen = (a >= min_alpha) & np.isfinite(d) & (np.abs(d - z[idx]) <= tolerance)
        idx, a = idx[seen], a[seen]
        to_cam = cam.centre[None, :] - texels.position[idx]
        to_cam /= np.maximum(np.linalg.norm(to_cam, axis=1, keepdims=True), 1e-30)
        cos = np.einsum("ij,ij->i", to_cam, texels.normal[idx])
        w = np.maximum(cos, 0.0) ** power * a
        rgb = _bilinear(view.rgb.astype(np.float64), u[idx], v[idx])
        al = _bilinear(view.alpha.astype(np.float64)[..., None], u[idx], v[idx])
        rgb = rgb / np.maximum(al, 1e-6)
        colour[idx] += w[:, None] * rgb
        weight[idx] += w
        if progress is not None:
            progress(i + 1, len(views))
    return colour, weight


def fill_texture(image: np.ndarray, known: np.ndarray, *, dilate: int = 4) -> np.ndarray:
    """Fill texels where `known` is False: `dilate` rounds of neighbour means, then push-pull."""
    img = np.array(image, np.float64)
    known = np.array(known, bool)
    img[~known] = 0.0
    for _ in range(dilate):
        if known.all():
            break
        s = np.zeros_like(img)
        c = np.zeros(known.shape, np.float64)
        padded = np.pad(img * known[..., None], ((1, 1), (1, 1), (0, 0)))
        pk = np.pad(known.astype(np.float64), 1)
        h, w = known.shape
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                if dx == 0 and dy == 0:
                    continue
                s += padded[1 + dy:1 + dy + h, 1 + dx:1 + dx + w]
                c += pk[1 + dy:1 + dy + h, 1 + dx:1 + dx + w]
        grow = ~known & (c > 0)
        img[grow] = s[grow] / c[grow][:, None]
        known = known | grow
    if not known.all():
        img = _push_pull(img, known)
    return img


def _push_pull(img: np.ndarray, known: np.ndarray) -> np.ndarray:
    h, w = known.shape
    if h <= 1 and w <= 1 or not known.any():
        out = img.copy()
        if not known.any():
            out[...] = 0.5
        return out
    hh, ww = (h + 1) // 2, (w + 1) // 2
    pad_img = np.zeros((hh * 2, ww * 2, img.shape[2]))
    pad_k = np.zeros((hh * 2, ww * 2))
    pad_img[:h, :w] = img * known[..., None]
    pad_k[:h, :w] = known
    s = pad_img.reshape(hh, 2, ww, 2, -1).sum(axis=(1, 3))
    c = pad_k.reshape(hh, 2, ww, 2).sum(axis=(1, 3))
    coarse = np.where(c[..., None] > 0, s / np.maximum(c, 1)[..., None], 0.0)
    coarse = _push_pull(coarse, c > 0)
    up = np.repeat(np.repeat(coarse, 2, axis=0), 2, axis=1)[:h, :w]
    return np.where(known[..., None], img, up)


@dataclass
class ProjectedTexture:
    image: np.ndarray     # (size, size, 3) float32 in [0, 1], row 0 = v 0
    coverage: float       # fraction of the triangles' texels some view saw
    corner_uvs: np.ndarray


def project_texture(vertices: np.ndarray, faces: np.ndarray, views: Sequence[View], size: int,
                    *, tolerance: float, corner_uvs: np.ndarray | None = None, power: float = 2.0,
                    dilate: int = 4, cancel: Callable[[], bool] | None = None,
                    progress: Callable[[int, int], None] | None = None) -> ProjectedTexture:
    """Unwrap (unless `corner_uvs` are given), rasterise the UV layout and project `views`."""
    if size < 4:
        raise ValueError(f"texture size must be at least 4, got {size}")
    if corner_uvs is None:
        corner_uvs = unwrap(vertices, faces, size)
    texels = rasterise_uv(vertices, faces, corner_uvs, size)
    colour, weight = project_views(texels, views, tolerance=tolerance, power=power,
                                   cancel=cancel, progress=progress)
    image = np.zeros((size * size, 3), np.float64)
    known = np.zeros(size * size, bool)
    seen = weight > 0
    image[texels.texel[seen]] = colour[seen] / weight[seen, None]
    known[texels.texel[seen]] = True
    coverage = float(seen.mean()) if len(seen) else 0.0
    image = fill_texture(image.reshape(size, size, 3), known.reshape(size, size), dilate=dilate)
    return ProjectedTexture(np.clip(image, 0.0, 1.0).astype(np.float32), coverage,
                            np.asarray(corner_uvs))
