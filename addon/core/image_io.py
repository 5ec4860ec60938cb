"""Writing rendered images to disk (OpenImageIO), atomically.

Renders are premultiplied inside; 8/16-bit formats such as PNG store straight alpha, so the
conversion happens here, at the file boundary, and nowhere else.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np


def unpremultiply(rgb: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Straight colour from premultiplied colour; zero where alpha is zero."""
    a = alpha[..., None]
    return np.divide(rgb, a, out=np.zeros_like(rgb), where=a > 0)


def write_image(path: str | os.PathLike, rgb: np.ndarray, alpha: np.ndarray | None = None) -> None:
    """Write premultiplied `rgb` (H, W, 3) and optional `alpha` (H, W) to `path`.

    The format follows from the extension. Integer formats (PNG, JPEG, TIFF) get straight alpha
    and values clamped to [0, 1]; float formats (EXR) keep premultiplied floats as they are.
    """
    import OpenImageIO as oiio

    path = Path(path)
    channels = rgb if alpha is None else np.concatenate([rgb, alpha[..., None]], axis=2)
    float_format = path.suffix.lower() in (".exr", ".hdr")
    if not float_format:
        if alpha is not None:
            channels = np.concatenate([unpremultiply(rgb, alpha), alpha[..., None]], axis=2)
        channels = np.clip(channels, 0.0, 1.0)
    height, width, count = channels.shape
    spec = oiio.ImageSpec(width, height, count, "float" if float_format else "uint8")
    if count == 4:
        spec.alpha_channel = 3
    tmp = path.with_name(f".{path.name}.tmp{path.suffix}")
    out = oiio.ImageOutput.create(str(tmp))
    if out is None or not out.open(str(tmp), spec):
        raise OSError(f"{path}: cannot write image: {oiio.geterror()}")
    try:
        if not out.write_image(np.ascontiguousarray(channels, dtype=np.float32)):
            raise OSError(f"{path}: cannot write image: {out.geterror()}")
    finally:
        out.close()
    os.replace(tmp, path)
