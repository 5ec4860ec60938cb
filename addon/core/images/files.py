"""Images on disk (OpenImageIO): headers, pixels in any bit depth, orientation, resizing, the
resampling that undistorts photos, rendered images out, and the one OpenImageIO writer (atomic:
a temporary file, then a rename) that `exr_layers` uses too.

Pixels stay in the file's own type until asked for (`uint8`, `uint16`, `half`, `float`), so a
cache of decoded photos costs what the files hold, not four bytes a channel. Values are as
stored: 8/16-bit photos are display-referred (sRGB) in [0, 1], float formats (EXR) keep
whatever they hold (usually scene-linear).

Alpha: renders are premultiplied inside; 8/16-bit formats such as PNG store straight alpha, so
`write_image` converts at the file boundary, and nowhere else.

Orientation: COLMAP (pycolmap's `Bitmap`) works on the pixels as stored and ignores the EXIF
orientation tag, so a photo is used as stored when its size matches its COLMAP camera, and
turned upright (`orientation` applied) only when it is the upright size that matches.

OpenImageIO ships with Blender (and is in requirements.txt for plain Python); it is imported on
first use, so importing this module costs nothing and works without it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from .. import native
from ..atomic import atomic_path

_TYPES = {"uint8": np.uint8, "uint16": np.uint16, "half": np.float16, "float": np.float32}
_SCALE = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}


class ImageError(OSError):
    """An image that cannot be read or written; the message names the file."""


@dataclass(frozen=True)
class ImageHeader:
    path: Path
    width: int  # as stored
    height: int
    channels: int
    pixel_type: str  # "uint8" | "uint16" | "half" | "float"
    orientation: int  # EXIF orientation, 1..8 (1 = as stored)
    focal_35mm: float = 0.0  # EXIF FocalLengthIn35mmFilm (0: not in the file)

    def size(self, oriented: bool) -> tuple[int, int]:
        """(width, height) as stored, or after turning the photo upright."""
        if oriented and self.orientation in (5, 6, 7, 8):
            return self.height, self.width
        return self.width, self.height


def _pixel_type(spec) -> str:
    name = str(spec.format)
    if name in ("uint8", "uint16", "half", "float"):
        return name
    if name in ("int8", "int16"):  # rare; read as the unsigned type of the same size
        return "u" + name
    return "float"  # double, uint32, ...: read as float


def read_header(path: str | os.PathLike) -> ImageHeader:
    """Size, channels, pixel type and orientation, without decoding the pixels."""
    import OpenImageIO as oiio

    path = Path(path)
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ImageError(f"{path}: cannot read image: {oiio.geterror() or 'unknown format'}")
    try:
        spec = inp.spec()
        orientation = spec.get_int_attribute("Orientation", 1)
        return ImageHeader(path, spec.width, spec.height, spec.nchannels, _pixel_type(spec),
                           orientation if 1 <= orientation <= 8 else 1,
                           spec.get_float_attribute("Exif:FocalLengthIn35mmFilm", 0.0))
    finally:
        inp.close()


def check_decodes(path: str | os.PathLike) -> None:
    """ImageError unless every pixel of the file decodes (`ImageBuf` fills what a truncated
    JPEG lacks with grey and reports nothing; `ImageInput` reports it)."""
    import OpenImageIO as oiio

    path = Path(path)
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ImageError(f"{path}: cannot read image: {oiio.geterror() or 'unknown format'}")
    try:
        pixels = inp.read_image("uint8")
        error = inp.geterror()  # a truncated JPEG: pixels (partly grey) and an error
        if pixels is None or error:
            raise ImageError(f"{path}: cannot read image: {error or 'no pixels'}")
    finally:
        inp.close()


def read_pixels(path: str | os.PathLike, *, orientation: int = 1,
                size: tuple[int, int] | None = None) -> np.ndarray:
    """The photo's pixels (H, W, C) in its own type (uint8, uint16, float16 or float32).

    `orientation` (EXIF, 1..8) is applied first (1 leaves the pixels as stored); `size`
    (width, height) then resizes with a box filter (an area average when shrinking).
    """
    import OpenImageIO as oiio

    path = Path(path)
    buf = oiio.ImageBuf(str(path))
    if buf.has_error or not buf.read():
        raise ImageError(f"{path}: cannot read image: {buf.geterror() or oiio.geterror()}")
    pixel_type = _pixel_type(buf.spec())
    if orientation != 1:
        buf.specmod().attribute("Orientation", int(orientation))
        buf = oiio.ImageBufAlgo.reorient(buf)
    if size is not None and (buf.spec().width, buf.spec().height) != tuple(size):
        width, height = size
        buf = oiio.ImageBufAlgo.resize(buf, filtername="box",
                                       roi=oiio.ROI(0, int(width), 0, int(height), 0, 1,
                                                    0, buf.nchannels))
    pixels = buf.get_pixels(getattr(oiio, {"uint8": "UINT8", "uint16": "UINT16",
                                          "half": "HALF", "float": "FLOAT"}[pixel_type]))
    if buf.has_error or pixels is None:
        raise ImageError(f"{path}: cannot read image: {buf.geterror()}")
    pixels = np.asarray(pixels)
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    return pixels.astype(_TYPES[pixel_type], copy=False)


def to_float(pixels: np.ndarray) -> np.ndarray:
    """Pixels as float32: integer types normalised to [0, 1], float types as they are."""
    scale = _SCALE.get(pixels.dtype)
    out = pixels.astype(np.float32)
    if scale is not None:
        out *= np.float32(1.0 / scale)
    return out


def rgb_float(pixels: np.ndarray, *, threads: int = 0) -> np.ndarray:
    """(H, W, 3) float32 colour of (H, W, C) pixels: `to_float(rgb_alpha(pixels)[0])`, bit for
    bit. 8-bit colour (3 or more channels, the usual photo) converts natively on `threads`
    threads (0: every core), what a training step does with its photo; the rest in NumPy."""
    if pixels.dtype == np.uint8 and pixels.ndim == 3 and pixels.shape[2] >= 3:
        out = np.empty(pixels.shape[:2] + (3,), np.float32)
        native.photo_rgb(np.ascontiguousarray(pixels), out, threads=threads)
        return out
    return to_float(rgb_alpha(pixels)[0])


def rgb_alpha(pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """(H, W, 3) colour and (H, W) alpha or None, from 1 to 4+ channels (grey is repeated)."""
    channels = pixels.shape[2]
    if channels == 1:
        return np.repeat(pixels, 3, axis=2), None
    if channels == 2:  # grey + alpha
        return np.repeat(pixels[:, :, :1], 3, axis=2), pixels[:, :, 1]
    alpha = pixels[:, :, 3] if channels >= 4 else None
    return pixels[:, :, :3], alpha


def write_pixels(path: str | os.PathLike, pixels: np.ndarray, *, jpeg_quality: int = 95,
                 straight_alpha: bool = False) -> None:
    """Write (H, W, C) pixels in their own type, atomically (a temporary file, then a rename).

    The format follows the extension; JPEG gets `jpeg_quality`. Colour with an alpha channel is
    taken as premultiplied (OpenImageIO's convention, as `read_pixels` returns it) unless
    `straight_alpha`, which stores it as given in formats with straight alpha (PNG).
    """
    import OpenImageIO as oiio

    path = Path(path)
    pixels = np.ascontiguousarray(pixels)
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    type_name = {np.dtype(v): k for k, v in _TYPES.items()}.get(pixels.dtype)
    if type_name is None:
        raise ImageError(f"{path}: cannot write pixels of type {pixels.dtype}")
    height, width, channels = pixels.shape
    spec = oiio.ImageSpec(width, height, channels, type_name)
    if channels in (2, 4):
        spec.alpha_channel = channels - 1
        if straight_alpha:
            spec.attribute("oiio:UnassociatedAlpha", 1)
    if path.suffix.lower() in (".jpg", ".jpeg"):
        spec.attribute("Compression", f"jpeg:{int(jpeg_quality)}")
    path.parent.mkdir(parents=True, exist_ok=True)
    write_subimages(path, [(spec, pixels)])


def write_subimages(path: str | os.PathLike, images: Sequence[tuple[object, np.ndarray]]) -> None:
    """Write one or more subimages (EXR parts), each an OpenImageIO `ImageSpec` and its
    (H, W, C) pixels, atomically. The format follows the extension."""
    import OpenImageIO as oiio

    path = Path(path)
    specs = [spec for spec, _ in images]
    with atomic_path(path) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None or not out.open(str(tmp), specs[0] if len(specs) == 1 else specs):
            reason = (out.geterror() if out is not None else "") or oiio.geterror()
            raise ImageError(f"{path}: cannot write image: {reason}")
        try:
            for index, (spec, pixels) in enumerate(images):
                if (index and not out.open(str(tmp), spec, "AppendSubimage")) \
                        or not out.write_image(pixels):
                    part = f" part {index}" if len(images) > 1 else ""
                    raise ImageError(f"{path}: cannot write image{part}: {out.geterror()}")
        finally:
            out.close()


def unpremultiply(rgb: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Straight colour from premultiplied colour; zero where alpha is zero."""
    a = alpha[..., None]
    return np.divide(rgb, a, out=np.zeros_like(rgb), where=a > 0)


def write_image(path: str | os.PathLike, rgb: np.ndarray, alpha: np.ndarray | None = None) -> None:
    """Write premultiplied `rgb` (H, W, 3) and optional `alpha` (H, W) to `path`, atomically.

    The format follows from the extension. Integer formats (PNG, JPEG, TIFF) get straight alpha
    and 8-bit values clamped to [0, 1]; float formats (EXR, HDR) keep premultiplied floats.
    """
    path = Path(path)
    if path.suffix.lower() in (".exr", ".hdr"):
        channels = rgb if alpha is None else np.concatenate([rgb, alpha[..., None]], axis=2)
        write_pixels(path, np.ascontiguousarray(channels, dtype=np.float32))
        return
    colour = rgb if alpha is None else unpremultiply(rgb, alpha)
    channels = colour if alpha is None else np.concatenate([colour, alpha[..., None]], axis=2)
    write_pixels(path, (np.clip(channels, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8),
                 straight_alpha=alpha is not None)


def remap_bilinear(pixels: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Sample `pixels` (H, W, C) at continuous pixel coordinates `x`, `y` (any equal shape S).

    Coordinates use the convention of `Camera`: pixel i covers [i, i+1], its centre is at
    i + 0.5. Bilinear between pixel centres; within half a pixel of the border the edge pixel
    is repeated; samples further out (or NaN) are 0. Returns shape S + (C,) in the input's
    type (integers rounded).
    """
    height, width, channels = pixels.shape
    fx = np.asarray(x, np.float64) - 0.5
    fy = np.asarray(y, np.float64) - 0.5
    valid = (fx >= -0.5) & (fx <= width - 0.5) & (fy >= -0.5) & (fy <= height - 0.5)  # NaN: False
    fx = np.clip(np.where(valid, fx, 0.0), 0.0, width - 1.0)
    fy = np.clip(np.where(valid, fy, 0.0), 0.0, height - 1.0)
    x0 = np.minimum(fx.astype(np.int64), max(width - 2, 0))
    y0 = np.minimum(fy.astype(np.int64), max(height - 2, 0))
    x1 = np.minimum(x0 + 1, width - 1)
    y1 = np.minimum(y0 + 1, height - 1)
    wx = (fx - x0).astype(np.float32)[..., None]
    wy = (fy - y0).astype(np.float32)[..., None]
    src = pixels.astype(np.float32, copy=False)
    top = src[y0, x0] * (1 - wx) + src[y0, x1] * wx
    bottom = src[y1, x0] * (1 - wx) + src[y1, x1] * wx
    out = top * (1 - wy) + bottom * wy
    out[~valid] = 0.0
    if pixels.dtype.kind in "ui":
        info = np.iinfo(pixels.dtype)
        return np.clip(np.rint(out), info.min, info.max).astype(pixels.dtype)
    return out.astype(pixels.dtype)
