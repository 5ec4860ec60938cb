"""Colour spaces: the one place that converts between Blender's scene-linear colour and the
display sRGB the splats were trained in.

Blender renders meshes in scene-linear Rec.709 (premultiplied alpha); splats trained on photos
hold display sRGB colours, and the reference 3DGS rasterizer blends them in that space. The
composite of the two (`addon.core.composite`) therefore happens in display sRGB: the mesh layer
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

_LINEAR_CUT = 0.0031308
_ENCODED_CUT = 0.04045


def _float(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x)
    return x if x.dtype.kind == "f" else x.astype(np.float64)


def srgb_encode(x: np.ndarray) -> np.ndarray:
    """Scene-linear -> display sRGB (the "Standard" view transform), elementwise (a new array,
    of x's float type)."""
    x = _float(x)
    a = np.abs(x)
    out = np.maximum(a, x.dtype.type(_LINEAR_CUT))
    np.power(out, x.dtype.type(1.0 / 2.4), out=out)
    out *= x.dtype.type(1.055)
    out -= x.dtype.type(0.055)
    np.multiply(a, x.dtype.type(12.92), out=out, where=a <= _LINEAR_CUT)
    negative = x < 0
    if negative.any():
        np.negative(out, out=out, where=negative)
    return out


def srgb_decode(y: np.ndarray) -> np.ndarray:
    """Display sRGB -> scene-linear, elementwise (the inverse of `srgb_encode`)."""
    y = _float(y)
    a = np.abs(y)
    out = np.maximum(a, y.dtype.type(_ENCODED_CUT))
    out += y.dtype.type(0.055)
    out *= y.dtype.type(1.0 / 1.055)
    np.power(out, y.dtype.type(2.4), out=out)
    np.multiply(a, y.dtype.type(1.0 / 12.92), out=out, where=a <= _ENCODED_CUT)
    negative = y < 0
    if negative.any():
        np.negative(out, out=out, where=negative)
    return out


def _premultiplied(rgba: np.ndarray, transfer) -> np.ndarray:
    rgba = np.asarray(rgba)
    dtype = np.float64 if rgba.dtype == np.float64 else np.float32
    out = np.ascontiguousarray(rgba, dtype=dtype)
    alpha = out[..., 3].copy()
    # The transfer runs over all four channels (numpy's fast loops want contiguous data);
    # alpha is put back after.
    if (alpha == 1).all():  # opaque (the usual film): no division
        out = transfer(out)
    else:
        scale = np.where(alpha > 0, alpha, dtype(1))[..., None]
        out = transfer(out / scale)
        out *= scale
    out[..., 3] = alpha
    return out


def display_from_linear(rgba: np.ndarray) -> np.ndarray:
    """Premultiplied scene-linear RGBA (..., 4) -> premultiplied display sRGB RGBA (a copy)."""
    return _premultiplied(rgba, srgb_encode)


def linear_from_display(rgba: np.ndarray) -> np.ndarray:
    """Premultiplied display sRGB RGBA (..., 4) -> premultiplied scene-linear RGBA (a copy)."""
    return _premultiplied(rgba, srgb_decode)
