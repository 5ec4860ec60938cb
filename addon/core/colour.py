"""Colour spaces: the one place that converts between Blender's scene-linear colour and the
display sRGB the splats were trained in.

Blender renders meshes in scene-linear Rec.709 (premultiplied alpha); splats trained on photos
hold display sRGB colours, and the reference 3DGS rasterizer blends them in that space. The
composite of the two (`addon.core.render.composite`) therefore happens in display sRGB: the mesh layer
goes through `display_from_linear`, the native compositor blends, and the result comes back
through `linear_from_display`. Blender's "Standard" view transform applies exactly the sRGB
encoding below when it writes or shows the result, so:

    splat-only pixels under "Standard" == the reference 3DGS render of those splats,

and mesh-only pixels are unchanged (the two conversions are inverses, to float rounding).
Other view transforms (AgX, Filmic, Khronos PBR Neutral, ...), looks, exposure and gamma act on
the composite like on any scene-linear image: the splats then look tone-mapped exactly as a
photo decoded to linear and shown through that view would.

The sRGB transfer function (IEC 61966-2-1), extended to all reals so that it stays invertible
for HDR values above 1 and for negative values (mirrored), as OpenColorIO's piecewise sRGB does:

    encode(x) = 12.92 x                       for |x| <= 0.0031308
              = sign(x) (1.055 |x|^(1/2.4) - 0.055)   otherwise
    decode(y) = y / 12.92                     for |y| <= 0.04045
              = sign(y) ((|y| + 0.055) / 1.055)^2.4    otherwise

Premultiplied colour converts through the straight colour: `a * f(rgb / a)`. A pixel with zero
alpha but some colour (additive light, e.g. an emitter over a transparent film) converts as if
its alpha were 1, which keeps the pair of conversions exact inverses.
"""

from __future__ import annotations

import numpy as np

from . import native

_LINEAR_CUT = 0.0031308
_ENCODED_CUT = 0.04045
# Values per block: the transfer makes several passes over its data (NumPy ufuncs, one
# operation each), so it runs block by block, the block and its temporaries in the CPU's cache.
_BLOCK = 1 << 17


def _float(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x)
    return x if x.dtype.kind == "f" else x.astype(np.float64)


class _Scratch:
    """Per-block temporaries, made once per call."""

    def __init__(self, dtype: np.dtype, size: int) -> None:
        self.magnitude = np.empty(size, dtype)
        self.mask = np.empty(size, bool)
        self.negative = np.empty(size, bool)


def _transfer_block(x: np.ndarray, out: np.ndarray, scratch: _Scratch, cut: float,
                    curve, slope: float) -> None:
    """One sRGB transfer over a 1-D block, into `out` (which may be `x` itself): `curve` (in
    place, on magnitudes clamped below at `cut`) above `cut`, `slope * |x|` at and below it,
    the sign put back. Blocks with no negative value (and no NaN: `min` is NaN then) skip the
    magnitudes, and blocks with nothing at or below `cut` skip the linear segment: the same
    values, fewer passes."""
    t = x.dtype.type
    n = len(x)
    a, small, negative = scratch.magnitude[:n], scratch.mask[:n], scratch.negative[:n]
    low = x.min() if n else t(1)
    if low > cut:  # the usual case: no negative value, no NaN, nothing on the linear segment
        curve(x, out)
        return
    signed = not low >= 0
    if signed:
        np.less(x, 0, out=negative)
    np.abs(x, out=a)  # also -0 -> +0
    np.less_equal(a, cut, out=small)
    np.maximum(a, t(cut), out=out)
    curve(out, out)
    a *= t(slope)
    np.copyto(out, a, where=small)
    if signed:
        np.negative(out, out=out, where=negative)


def _encode_curve(x: np.ndarray, out: np.ndarray) -> None:
    t = x.dtype.type
    np.power(x, t(1.0 / 2.4), out=out)
    out *= t(1.055)
    out -= t(0.055)


def _decode_curve(y: np.ndarray, out: np.ndarray) -> None:
    t = y.dtype.type
    np.add(y, t(0.055), out=out)
    out *= t(1.0 / 1.055)
    np.power(out, t(2.4), out=out)


def _encode_block(x: np.ndarray, out: np.ndarray, scratch: _Scratch) -> None:
    """srgb_encode of a 1-D block into `out` (which may be `x` itself)."""
    _transfer_block(x, out, scratch, _LINEAR_CUT, _encode_curve, 12.92)


def _decode_block(y: np.ndarray, out: np.ndarray, scratch: _Scratch) -> None:
    """srgb_decode of a 1-D block into `out` (which may be `y` itself)."""
    _transfer_block(y, out, scratch, _ENCODED_CUT, _decode_curve, 1.0 / 12.92)


def _elementwise(x: np.ndarray, block) -> np.ndarray:
    x = _float(x)
    out = np.empty(x.shape, x.dtype)
    flat_in, flat_out = np.ascontiguousarray(x).reshape(-1), out.reshape(-1)
    scratch = _Scratch(x.dtype, min(_BLOCK, flat_in.size))
    for start in range(0, flat_in.size, _BLOCK):
        block(flat_in[start:start + _BLOCK], flat_out[start:start + _BLOCK], scratch)
    return out


def srgb_encode(x: np.ndarray) -> np.ndarray:
    """Scene-linear -> display sRGB (the "Standard" view transform), elementwise (a new array,
    of x's float type)."""
    return _elementwise(x, _encode_block)


def srgb_decode(y: np.ndarray) -> np.ndarray:
    """Display sRGB -> scene-linear, elementwise (the inverse of `srgb_encode`)."""
    return _elementwise(y, _decode_block)


def _convert_pixels(src: np.ndarray, dst: np.ndarray, block, scratch: _Scratch) -> None:
    """Premultiplied (n, 4) pixels through `block` (see `_premultiplied`), into `dst` (which may
    be `src` itself)."""
    one = src.dtype.type(1)
    alpha = src[:, 3].copy()
    # The transfer runs over all four channels (numpy's fast loops want contiguous data);
    # alpha is put back after.
    if (alpha == one).all():  # opaque (the usual film): no division (x / 1 is x anyway)
        block(src.reshape(-1), dst.reshape(-1), scratch)
    else:
        scale = np.where(alpha > 0, alpha, one)[:, None]
        np.divide(src, scale, out=dst)
        block(dst.reshape(-1), dst.reshape(-1), scratch)
        dst *= scale
    dst[:, 3] = alpha


def _runs(pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(first pixel, length) of each run of bit-identical neighbouring pixels, or None when
    there are too many runs to be worth it. A world background or a transparent film is one
    colour over most of a frame: converting one pixel per run is the same, bit for bit."""
    if len(pixels) < 2:
        return None
    words = pixels.view(np.uint64)
    same = words[1:, 0] == words[:-1, 0]
    for column in range(1, words.shape[1]):
        same &= words[1:, column] == words[:-1, column]
    breaks = np.flatnonzero(~same)
    if 4 * (len(breaks) + 1) > len(pixels):
        return None
    first = np.empty(len(breaks) + 1, np.intp)
    first[0] = 0
    np.add(breaks, 1, out=first[1:])
    return first, np.diff(first, append=len(pixels))


def _premultiplied(rgba: np.ndarray, block, out: np.ndarray | None, threads: int,
                   zero_non_finite: bool = False) -> np.ndarray:
    rgba = np.asarray(rgba)
    dtype = np.dtype(np.float64 if rgba.dtype == np.float64 else np.float32)
    if out is None:
        out = np.empty(rgba.shape, dtype)
    if out.shape != rgba.shape or out.dtype != dtype or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous {dtype} array of shape {rgba.shape}")
    if rgba.ndim < 1 or rgba.shape[-1] != 4:
        raise ValueError(f"rgba must have shape (..., 4), got {rgba.shape}")
    if dtype == np.float32:
        # Native, on the thread pool: each value in double, rounded once (within about half a
        # float32 ulp of the float64 transfer). An image is read with its own strides (views
        # of a file's planar channels: no copy).
        source = rgba.astype(dtype, copy=False)
        if out is not source and np.shares_memory(out, source):
            source = source.copy()
        image = source if source.ndim == 3 else source.reshape(1, -1, 4)
        native.srgb_view(image, out.reshape(image.shape), block is _decode_block,
                         zero_non_finite, threads)
        return out
    result, out = out, out.reshape(-1, 4)
    source = np.ascontiguousarray(rgba, dtype=dtype).reshape(-1, 4)
    pixels = _BLOCK // 4
    scratch = _Scratch(dtype, _BLOCK)
    for start in range(0, len(source), pixels):
        src, dst = source[start:start + pixels], out[start:start + pixels]
        runs = _runs(src)
        if runs is None:
            _convert_pixels(src, dst, block, scratch)
        else:
            first, lengths = runs
            distinct = src[first]
            _convert_pixels(distinct, distinct, block, scratch)
            dst[...] = np.repeat(distinct, lengths, axis=0)
    if zero_non_finite:
        np.nan_to_num(result, copy=False, nan=0.0, posinf=0.0, neginf=0.0)
    return result


def display_from_linear(rgba: np.ndarray, out: np.ndarray | None = None, *,
                        threads: int = 0, zero_non_finite: bool = False) -> np.ndarray:
    """Premultiplied scene-linear RGBA (..., 4) -> premultiplied display sRGB RGBA (a copy, or
    written into `out`: C-contiguous, rgba's shape, float32 or float64 for float64 input).
    Float32 converts natively on `threads` threads (0: every core; the same bits on any
    count), float64 in NumPy. With `zero_non_finite`, non-finite results (alpha too) are 0 (a
    mesh layer for the compositor)."""
    return _premultiplied(rgba, _encode_block, out, threads, zero_non_finite)


def linear_from_display(rgba: np.ndarray, out: np.ndarray | None = None, *,
                        threads: int = 0) -> np.ndarray:
    """Premultiplied display sRGB RGBA (..., 4) -> premultiplied scene-linear RGBA (a copy, or
    written into `out`, as for `display_from_linear`)."""
    return _premultiplied(rgba, _decode_block, out, threads)
