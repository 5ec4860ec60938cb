"""Lossless 8-bit RGBA WebP images through OpenImageIO, as raw bytes (no colour management).

SOG stores quantised numbers in WebP pixels, so every byte must come back as written:
- written with `compression="lossless"` and `oiio:UnassociatedAlpha` (OpenImageIO would
  otherwise un-premultiply RGB by alpha), read with the same hint (it would otherwise premultiply);
- one exception is libwebp's: RGB under alpha 0 is not kept (the encoder's `exact` option is
  off and OpenImageIO does not expose it). Callers put nothing but "don't care" there.

OpenImageIO is imported on first use: Blender bundles it (with WebP), but a stripped Python may
lack it, and the other formats must still load then.
"""

from __future__ import annotations

import os
from pathlib import Path
from types import ModuleType

import numpy as np

from .errors import SplatFileError

__all__ = ["read_size", "read_rgba", "write_rgba", "MAX_SIDE"]

MAX_SIDE = 16383  # the WebP format's largest width and height


def _oiio(path: Path) -> ModuleType:
    try:
        import OpenImageIO as oiio
    except ImportError:
        raise SplatFileError(path, "WebP images need the Python module 'OpenImageIO', which is not "
                                   "installed in this Python") from None
    return oiio


def _open(path: Path, shown: str | os.PathLike, what: str):
    oiio = _oiio(Path(shown))
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    image = oiio.ImageInput.open(str(path), config)
    if image is None:  # OpenImageIO's message names `path`, which may be a temporary file
        problem = (oiio.geterror() or "unknown format").replace(str(path), what)
        raise SplatFileError(shown, f"cannot read image {what}: {problem}")
    return image


def read_size(path: str | os.PathLike, shown: str | os.PathLike | None = None,
              what: str = "") -> tuple[int, int, int]:
    """(width, height, channels) from the image header alone: nothing is decoded. Errors name
    `shown` (the user's file; `path` by default) and `what` (the image inside it)."""
    path = Path(path)
    shown, what = shown or path, what or path.name
    image = _open(path, shown, what)
    try:
        spec = image.spec()
        return int(spec.width), int(spec.height), int(spec.nchannels)
    finally:
        image.close()


def read_rgba(path: str | os.PathLike, shown: str | os.PathLike | None = None,
              what: str = "") -> np.ndarray:
    """The image as (H, W, 4) uint8, bytes as stored; a missing alpha channel reads as 255.
    Errors name `shown` and `what`, as `read_size`'s."""
    path = Path(path)
    shown, what = shown or path, what or path.name
    image = _open(path, shown, what)
    try:
        spec = image.spec()
        if not (0 < spec.width <= MAX_SIDE and 0 < spec.height <= MAX_SIDE) or spec.nchannels not in (3, 4):
            raise SplatFileError(shown, f"unsupported image {what}: {spec.width}x{spec.height}, "
                                        f"{spec.nchannels} channels (expected RGB or RGBA WebP)")
        pixels = image.read_image(0, 0, 0, spec.nchannels, "uint8")
        if pixels is None:
            problem = (image.geterror() or "unknown error").replace(str(path), what)
            raise SplatFileError(shown, f"cannot decode image {what}: {problem}")
    finally:
        image.close()
    pixels = np.asarray(pixels, np.uint8).reshape(spec.height, spec.width, spec.nchannels)
    if spec.nchannels == 3:
        pixels = np.concatenate([pixels, np.full(pixels.shape[:2] + (1,), 255, np.uint8)], axis=2)
    return pixels


def write_rgba(path: str | os.PathLike, pixels: np.ndarray) -> None:
    """Write (H, W, 4) uint8 as a lossless WebP at `path` (not atomic: callers write into a
    temporary folder or file and move it into place)."""
    path = Path(path)
    oiio = _oiio(path)
    pixels = np.ascontiguousarray(pixels, dtype=np.uint8)
    height, width, channels = pixels.shape
    if channels != 4 or not (0 < width <= MAX_SIDE and 0 < height <= MAX_SIDE):
        raise SplatFileError(path, f"cannot write a {width}x{height}x{channels} WebP image "
                                   f"(at most {MAX_SIDE} a side, RGBA)")
    spec = oiio.ImageSpec(width, height, 4, "uint8")
    spec.attribute("compression", "lossless")
    spec.attribute("oiio:UnassociatedAlpha", 1)
    spec.alpha_channel = 3
    out = oiio.ImageOutput.create(str(path))
    if out is None or not out.open(str(path), spec):
        raise SplatFileError(path, f"cannot write image: {oiio.geterror()}")
    try:
        if not out.write_image(pixels):
            raise SplatFileError(path, f"cannot write image: {out.geterror()}")
    finally:
        out.close()
