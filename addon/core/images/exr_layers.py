"""Blender's multilayer OpenEXR files: their channel naming, read and extended (no bpy).

Blender writes a multilayer EXR as one part per render pass, named `<layer>.<pass>` (or, as
Blender 4.x does and 5.0 does when asked, one part holding them all), with channels
`<layer>.<pass>.<channel>` (e.g. `ViewLayer.Combined.R`, `ViewLayer.Depth.Z`). Rows in the file
run top to bottom, as in every image here. Reading is OpenImageIO's, imported on first
use; writing goes through `files.write_subimages` (atomic).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterator

import numpy as np

from .files import ImageError, write_subimages


def _parts(path: Path, pixel_type: str | None = None) -> Iterator[tuple[object, np.ndarray]]:
    """Each part's OpenImageIO `ImageSpec` and its (H, W, C) pixels, read as `pixel_type`
    (None: the part's own type)."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ImageError(f"{path}: cannot read: {oiio.geterror()}")
    try:
        subimage = 0
        while inp.seek_subimage(subimage, 0):
            spec = inp.spec()
            pixels = inp.read_image(subimage, 0, 0, spec.nchannels, pixel_type or spec.format)
            if pixels is None:
                raise ImageError(f"{path}: cannot read part {subimage}: {inp.geterror()}")
            yield spec, np.asarray(pixels).reshape(spec.height, spec.width, spec.nchannels)
            subimage += 1
    finally:
        inp.close()


def read_channels(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Every channel of every part of an EXR: full channel name -> (H, W) float32."""
    channels: dict[str, np.ndarray] = {}
    for spec, pixels in _parts(Path(path), "float"):
        pixels = pixels.astype(np.float32, copy=False)
        for index, name in enumerate(spec.channelnames):
            channels[name] = pixels[..., index]
    return channels


def find_pass(channels: dict[str, np.ndarray], layer: str, name: str,
              components: str) -> np.ndarray | None:
    """The pass `<layer>.<name>` as (H, W, len(components)), or None if any channel is missing.
    Read-only channels spaced evenly in one buffer (an uncompressed file's rows, viewed by
    `exr_scanlines`) give a read-only view of them, no copy; others a stacked copy."""
    planes = [channels.get(f"{layer}.{name}.{c}") for c in components]
    if any(p is None for p in planes):
        return None
    view = _interleaved_view(planes)
    return view if view is not None else np.stack(planes, axis=-1)


def _root(array: np.ndarray) -> object:
    while isinstance(array.base, np.ndarray):
        array = array.base
    return array.base


def _interleaved_view(planes: list[np.ndarray]) -> np.ndarray | None:
    """The planes as one read-only (H, W, C) view when they are read-only views of one buffer
    with one layout, each the same distance from the one before: every element of the view is
    an element of a plane, and the buffer lives as long as the view."""
    first = planes[0]
    root = _root(first)
    if root is None or any(p.flags.writeable or p.dtype != first.dtype or p.shape != first.shape
                           or p.strides != first.strides or _root(p) is not root for p in planes):
        return None
    addresses = [p.__array_interface__["data"][0] for p in planes]
    step = addresses[1] - addresses[0] if len(planes) > 1 else first.itemsize
    if any(b - a != step for a, b in zip(addresses, addresses[1:])):
        return None
    return np.lib.stride_tricks.as_strided(first, (*first.shape, len(planes)),
                                           (*first.strides, step), writeable=False)


def append_layers(path: str | os.PathLike, parts: dict[str, tuple[str, np.ndarray]]) -> None:
    """Rewrite the EXR at `path` with extra parts, keeping every existing part as it was
    (channels, pixels, compression and metadata); the file is replaced atomically.

    parts: part name (`<layer>.<pass>`) -> (channel letters such as "RGBA" or "Z", float32
    pixels (H, W, len(letters))). A part of the same name is replaced.
    """
    import OpenImageIO as oiio

    path = Path(path)
    images: list[tuple[object, np.ndarray]] = []
    for spec, pixels in _parts(path):
        name = spec.getattribute("name") or spec.getattribute("oiio:subimagename")
        if name not in parts:
            images.append((oiio.ImageSpec(spec), pixels))
    if not images:
        raise ImageError(f"{path}: no image parts")
    compression = images[-1][0].getattribute("compression") or "zip"
    for name, (letters, pixels) in parts.items():
        pixels = np.ascontiguousarray(pixels, np.float32)
        height, width = pixels.shape[:2]
        pixels = pixels.reshape(height, width, len(letters))
        spec = oiio.ImageSpec(width, height, len(letters), "float")
        spec.channelnames = tuple(f"{name}.{c}" for c in letters)
        spec.attribute("name", name)
        spec.attribute("compression", compression)
        if letters.endswith("A"):
            spec.alpha_channel = len(letters) - 1
        images.append((spec, pixels))
    write_subimages(path, images)


def write_channels(path: str | os.PathLike, channels: dict[str, np.ndarray], *,
                   compression: str = "none") -> None:
    """Write (H, W) float32 planes as one single-part EXR with those channel names (how
    Blender's `RenderResult.load_from_file` takes a whole render result), atomically."""
    import OpenImageIO as oiio

    names = list(channels)
    pixels = np.ascontiguousarray(np.stack([channels[n] for n in names], axis=-1), np.float32)
    height, width = pixels.shape[:2]
    spec = oiio.ImageSpec(width, height, len(names), "float")
    spec.channelnames = tuple(names)
    spec.attribute("compression", compression)
    write_subimages(path, [(spec, pixels)])
