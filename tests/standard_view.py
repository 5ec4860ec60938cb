"""What Blender's "Standard" view transform writes, spelled out here (no bpy): the colour
helpers the render tests (bpy and real Blender) hold written files against."""

from __future__ import annotations

import numpy as np

from addon.core.render.renderer import render


def encode(x):
    x = np.asarray(x, np.float64)
    a = np.abs(x)
    return np.sign(x) * np.where(a <= 0.0031308, 12.92 * a, 1.055 * np.maximum(a, 1e-12) ** (1 / 2.4) - 0.055)


def decode(y):
    y = np.asarray(y, np.float64)
    a = np.abs(y)
    return np.sign(y) * np.where(a <= 0.04045, a / 12.92, ((a + 0.055) / 1.055) ** 2.4)


def premultiplied(rgba, transfer):
    rgba = np.asarray(rgba, np.float64).copy()
    alpha = np.where(rgba[..., 3:] > 0, rgba[..., 3:], 1.0)
    rgba[..., :3] = transfer(rgba[..., :3] / alpha) * alpha
    return rgba


def standard_8bit(linear_rgba):
    """What Blender writes to an 8-bit RGBA PNG under the Standard view transform: straight
    colour, sRGB-encoded, rounded."""
    alpha = linear_rgba[..., 3:]
    straight = np.where(alpha > 0, linear_rgba[..., :3] / np.where(alpha > 0, alpha, 1), 0)
    out = np.concatenate([encode(straight), alpha], axis=-1)
    return np.round(np.clip(out, 0, 1) * 255).astype(np.int32)


def native_composite(gaussians, camera, mesh_rgba, mesh_depth, **options):
    """Linear premultiplied composite: the mesh layer to display sRGB, the native compositor,
    back to linear (`options`: the renderer's, e.g. near)."""
    result = render(gaussians, camera, mesh_rgba=premultiplied(mesh_rgba, encode).astype(np.float32),
                    mesh_depth=mesh_depth, **options)
    out = np.concatenate([result.rgb, result.alpha[..., None]], axis=-1)
    return premultiplied(out, decode)


def read_png(path) -> np.ndarray:
    import OpenImageIO as oiio

    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)  # the file's straight colour, as stored
    buf = oiio.ImageBuf(str(path), 0, 0, config)
    if buf.has_error:
        raise OSError(f"{path}: {buf.geterror()}")
    return np.asarray(buf.get_pixels(oiio.UINT8), np.int32)
