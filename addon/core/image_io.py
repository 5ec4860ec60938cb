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
    """Write premultiplied `rgb` (H, W, 3) and optional `alpha` (H, W) to `path`, atomically.

    The format follows from the extension. Integer formats (PNG, JPEG, TIFF) get straight alpha
    and 8-bit values clamped to [0, 1]; float formats (EXR, HDR) keep premultiplied floats.
    """
    from .photos import write_pixels

    path = Path(path)
    if path.suffix.lower() in (".exr", ".hdr"):
        channels = rgb if alpha is None else np.concatenate([rgb, alpha[..., None]], axis=2)
        write_pixels(path, np.ascontiguousarray(channels, dtype=np.float32))
        return
    colour = rgb if alpha is None else unpremultiply(rgb, alpha)
    channels = colour if alpha is None else np.concatenate([colour, alpha[..., None]], axis=2)
    write_pixels(path, (np.clip(channels, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8),
                 straight_alpha=alpha is not None)
