"""Splats composed with a mesh render, in Blender's colour conventions (no bpy).

`compose()` takes what Blender rendered (premultiplied scene-linear RGBA and planar depth, rows
top to bottom) and returns the exact composite of docs/conventions.md "Compositing with meshes", again as
premultiplied scene-linear RGBA: per pixel, the Gaussians in front of the mesh surface, the
mesh weighted by the transmittance left, then the Gaussians behind it (`addon.core.render.renderer`).

Colour (see `addon.core.colour`): splats whose colours are display sRGB (`color_space="SRGB"`,
what photos train) are blended in display sRGB, as the reference rasterizer blends them: the
mesh layer is encoded to display sRGB, composed, and the result decoded back to scene-linear.
Under Blender's "Standard" view transform, splat-only pixels are then the reference render
(over the world colour, or over transparency) and mesh-only pixels are unchanged. Splats marked
`"LINEAR"` are composed with the scene-linear mesh layer as they are.

`render_region()` reproduces which pixels Blender renders for a render border (with or without
"Crop to Render Region"). A border is composed by rendering the whole frame and keeping the
region (`embed` puts a cropped mesh layer back into the frame): a camera cropped to the region
would not give the same pixels, because the reference projection clamps the Jacobian to a guard
band that depends on the image's extent.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .. import colour
from ..cameras import Camera, image_coverage
from ..gaussians import Gaussians
from .. import native
from .renderer import render

# Blender's "nothing here" depth (Cycles, Workbench and EEVEE write 1e10 where no surface is).
FAR = 1e10
COLOR_SPACES = ("SRGB", "LINEAR")


@dataclass
class CompositeResult:
    rgba: np.ndarray          # (H, W, 4) float32 premultiplied scene-linear composite
    depth: np.ndarray | None  # (H, W) float32 expected planar depth (FAR where nothing was
                              # hit); None when not asked for (`compose(with_depth=False)`)
    stats: dict[str, float] = field(default_factory=dict)


@dataclass
class SplatLayer:
    rgba: np.ndarray       # (H, W, 4) float32 premultiplied scene-linear, the splats alone
    depth: np.ndarray      # (H, W) float32 expected planar depth (FAR where no splat)
    stats: dict[str, float] = field(default_factory=dict)


def _check_space(color_space: str) -> None:
    if color_space not in COLOR_SPACES:
        raise ValueError(f"color_space must be one of {COLOR_SPACES}, got {color_space!r}")


def _finite_depth(depth: np.ndarray) -> np.ndarray:
    depth = np.asarray(depth, np.float32)
    if np.isfinite(depth).all():
        return np.ascontiguousarray(depth)
    return np.nan_to_num(depth, nan=FAR, posinf=FAR, neginf=0.0)


def compose(gaussians: Gaussians, camera: Camera, mesh_rgba: np.ndarray, mesh_depth: np.ndarray,
            *, color_space: str = "SRGB", antialiased: bool = False, near: float = 0.01,
            sh_degree: int | None = None, threads: int = 0,
            out: np.ndarray | None = None, with_depth: bool = True,
            prepared: Prepared | None = None,
            coverage: np.ndarray | None | str = "camera") -> CompositeResult:
    """The exact composite of `gaussians` with a mesh render seen by `camera`.

    mesh_rgba: (H, W, 4) premultiplied scene-linear colour, rows top to bottom (float32 with
        any strides is read as it is: views of a file's planar channels need no copy).
    mesh_depth: (H, W) planar camera depth (Blender's Depth pass); non-finite values mean
        "nothing here" and become FAR.
    out: where the composite goes, (H, W, 4) float32 with any strides, overlapping none of the
        inputs (e.g. a row-reversed view of the buffer a Blender render pass is filled from,
        reused from frame to frame); by default a new array.
    with_depth: False when the composite's depth is not wanted (display sRGB only: its
        `depth` is then None, and the mesh depth is not read where no Gaussian reaches).
    prepared: `prepare(gaussians, camera, ...)` made beforehand with the same options (display
        sRGB only; made here when None).
    coverage: the pixels the camera shows (`cameras.image_coverage`, None: all), where the
        caller has it (a render finds it with the camera); by default found here.
    Returns premultiplied scene-linear RGBA (`out`) and the composite's expected depth.
    """
    _check_space(color_space)
    start = time.perf_counter()
    mesh_rgba = np.asarray(mesh_rgba, np.float32)
    height, width = camera.height, camera.width
    if mesh_rgba.shape != (height, width, 4):
        raise ValueError(f"mesh_rgba must have shape {(height, width, 4)}, "
                         f"got {mesh_rgba.shape}")
    if color_space == "SRGB":
        result = _compose_display(gaussians, camera, mesh_rgba, mesh_depth,
                                  antialiased=antialiased, near=near, sh_degree=sh_degree,
                                  threads=threads, out=out, with_depth=with_depth,
                                  prepared=prepared)
        return _outside_the_image_circle(result, camera, coverage, mesh_rgba, mesh_depth)
    layer = np.ascontiguousarray(mesh_rgba)
    if not np.isfinite(layer).all():
        layer = np.nan_to_num(layer, nan=0.0, posinf=0.0, neginf=0.0)
    convert_in = time.perf_counter() - start
    result = render(gaussians, camera, mesh_rgba=layer, mesh_depth=_finite_depth(mesh_depth),
                    antialiased=antialiased, near=near, sh_degree=sh_degree, threads=threads)
    start = time.perf_counter()
    if out is None:
        out = np.empty((height, width, 4), np.float32)
    out[..., :3] = result.rgb
    out[..., 3] = result.alpha
    depth = result.depth
    depth[~np.isfinite(depth)] = FAR
    stats = dict(result.stats)
    stats["colour_ms"] = 1000 * (convert_in + time.perf_counter() - start)
    return _outside_the_image_circle(CompositeResult(out, depth, stats), camera, coverage,
                                     mesh_rgba, mesh_depth)


def _outside_the_image_circle(result, camera: Camera, coverage, mesh_rgba, mesh_depth):
    """Where a fisheye or mirror ball shows nothing (`coverage`, "camera": `image_coverage`),
    Blender's own pixel, with no splats (a composite), or nothing (a splat layer: mesh_rgba
    None)."""
    shown = image_coverage(camera) if isinstance(coverage, str) else coverage
    if shown is None:
        return result
    outside = ~shown
    if mesh_rgba is None:
        result.rgba[outside] = 0.0
    else:
        result.rgba[outside] = mesh_rgba[outside]
    if result.depth is not None:
        result.depth[outside] = FAR if mesh_depth is None else \
            _finite_depth(np.asarray(mesh_depth, np.float32)[outside])
    return result


@dataclass
class Prepared:
    """The Gaussians' half of a display-sRGB composite (`prepare`): projected, sorted and binned
    for one camera; it needs no mesh render, so it can be made while Blender writes that out."""

    handle: object            # splatcore's prepared frame (freed with this object)
    camera: Camera
    threads: int
    stats: dict[str, float]


def prepare(gaussians: Gaussians, camera: Camera, *, antialiased: bool = False,
            near: float = 0.01, sh_degree: int | None = None, threads: int = 0) -> Prepared:
    """The first half of `compose` (display sRGB), for `compose(..., prepared=)`. Releases the
    GIL while it runs: another thread may do this while the main one reads the render."""
    threads = native.thread_count(threads)
    handle, stats = native.compose_prepare(gaussians, camera, sh_degree=sh_degree, near=near,
                                           antialiased=antialiased, threads=threads)
    return Prepared(handle, camera, threads, stats)


def _compose_display(gaussians: Gaussians, camera: Camera, mesh_rgba: np.ndarray,
                     mesh_depth: np.ndarray, *, antialiased: bool, near: float,
                     sh_degree: int | None, threads: int, out: np.ndarray | None,
                     with_depth: bool, prepared: Prepared | None) -> CompositeResult:
    """compose() in display sRGB, natively in one pass over the tiles (`sc_compose_srgb`):
    the mesh layer encoded, composed and the changed pixels decoded only in tiles a Gaussian
    reaches; elsewhere the mesh's own pixels. The same bits as encoding the whole layer
    (`colour.display_from_linear`, non-finite values zeroed), rendering over it (`render`) and
    decoding the changed pixels (`native.srgb_decode_changed`), frame-wide (tests hold it)."""
    if prepared is None:
        prepared = prepare(gaussians, camera, antialiased=antialiased, near=near,
                           sh_degree=sh_degree, threads=threads)
    elif prepared.camera is not camera:
        raise ValueError("prepared was made for another camera")
    height, width = camera.height, camera.width
    if out is None:
        out = np.empty((height, width, 4), np.float32)
    depth = np.empty((height, width), np.float32) if with_depth else None
    stats = native.compose_srgb(prepared.handle, mesh_rgba, np.asarray(mesh_depth, np.float32),
                                out, depth, FAR)
    # The conversions run inside the tile pass: their share of its wall time, on all threads.
    stats["colour_ms"] = stats["ms_colour_cpu"] / (prepared.threads or native.cpu_count())
    stats["native_ms"] = stats["ms_total"] - stats["colour_ms"]
    return CompositeResult(out, depth, stats)


def splat_layer(gaussians: Gaussians, camera: Camera, *, color_space: str = "SRGB",
                antialiased: bool = False, near: float = 0.01, sh_degree: int | None = None,
                threads: int = 0, background: np.ndarray | None = None,
                coverage: np.ndarray | None | str = "camera") -> SplatLayer:
    """The splats alone, as premultiplied scene-linear RGBA (their own colour, alpha and depth).

    background: an optional scene-linear RGB colour behind the splats; the result is then
    opaque (alpha 1), the splats composed over it in the splats' colour space.
    coverage: as `compose`'s.
    """
    _check_space(color_space)
    bg = None
    if background is not None:
        bg = np.asarray(background, np.float32).reshape(3)
        if color_space == "SRGB":
            bg = colour.srgb_encode(bg).astype(np.float32)
    result = render(gaussians, camera, background=bg, antialiased=antialiased, near=near,
                    sh_degree=sh_degree, threads=threads)
    start = time.perf_counter()
    out = np.empty((camera.height, camera.width, 4), np.float32)
    out[..., :3] = result.rgb
    out[..., 3] = 1.0 if bg is not None else result.alpha
    if color_space == "SRGB":
        out = colour.linear_from_display(out)
    depth = np.where(np.isfinite(result.depth), result.depth, np.float32(FAR)).astype(np.float32)
    stats = dict(result.stats)
    stats["colour_ms"] = 1000 * (time.perf_counter() - start)
    return _outside_the_image_circle(SplatLayer(out, depth, stats), camera, coverage, None, None)


@dataclass(frozen=True)
class Region:
    """Pixels of the full frame (rows top to bottom) that a render covers."""

    x: int         # first column
    y: int         # first row, from the top
    width: int
    height: int

    def slices(self) -> tuple[slice, slice]:
        return slice(self.y, self.y + self.height), slice(self.x, self.x + self.width)


def render_region(width: int, height: int, border: tuple[float, float, float, float] | None
                  ) -> Region:
    """The part of a `width` x `height` frame Blender renders for a render border
    `(min_x, max_x, min_y, max_y)` (fractions, y up), or the whole frame for None.

    Blender (`render_init_from_main`) truncates `border * size` to integers in float32
    arithmetic: `xmin = int(min_x * W)` and so on, y counted from the bottom.
    """
    if border is None:
        return Region(0, 0, width, height)
    f32 = np.float32
    min_x, max_x, min_y, max_y = (f32(v) for v in border)
    xmin, xmax = int(min_x * f32(width)), int(max_x * f32(width))
    ymin, ymax = int(min_y * f32(height)), int(max_y * f32(height))
    return Region(xmin, height - ymax, xmax - xmin, ymax - ymin)


def embed(rgba: np.ndarray, depth: np.ndarray, region: Region, width: int, height: int
          ) -> tuple[np.ndarray, np.ndarray]:
    """A full-frame mesh layer holding `rgba`, `depth` (which cover `region`); empty (alpha 0,
    depth FAR) elsewhere."""
    full_rgba = np.zeros((height, width, 4), np.float32)
    full_depth = np.full((height, width), FAR, np.float32)
    full_rgba[region.slices()] = rgba
    full_depth[region.slices()] = depth
    return full_rgba, full_depth


def apply_shadow_catcher(rgba: np.ndarray, shadow: np.ndarray) -> np.ndarray:
    """Darken a composite by Cycles' "Shadow Catcher" pass (docs/guide/meshes.md).

    With that pass on, Cycles leaves shadow catchers (the proxies of splat objects) out of the
    Combined pass: they are transparent there, so the splats they stand for are composed as if
    the catcher were not rendered at all, and the caught shadow is only in the pass, as a factor
    to multiply by (1: no shadow). The shadow is then laid over the finished composite as a
    black layer of opacity 1 - factor: premultiplied colour times the factor (per channel,
    clipped to [0, 1]: a catcher only darkens), alpha `a * s + (1 - s)` with `s` the channels'
    mean, so over transparent film the shadow stays visible as it does in Cycles' own
    transparent-film output. Pixels where the pass is 1 (no catcher, or a mesh in front of it)
    are returned unchanged, bit for bit.

    rgba: (H, W, 4) premultiplied; shadow: (H, W, 3) or (H, W, 4) (its alpha is ignored).
    """
    rgba = np.asarray(rgba, np.float32)
    shadow = np.asarray(shadow, np.float32)[..., :3]
    if shadow.size and shadow.min() >= 1.0:  # no shadow caught anywhere (NaN: min is NaN)
        return rgba.copy()
    factor = np.clip(np.nan_to_num(shadow, nan=1.0), 0.0, 1.0)
    shaded = factor.min(axis=-1) < 1.0
    out = rgba.copy()
    if shaded.any():
        f = factor[shaded]
        s = f.mean(axis=-1)
        out[shaded, :3] = rgba[shaded, :3] * f
        out[shaded, 3] = rgba[shaded, 3] * s + (1.0 - s)
    return out
