"""Blender's multilayer OpenEXR files, read and extended with OpenImageIO (no bpy).

Blender writes a multilayer EXR as one part per render pass, named `<layer>.<pass>`, with
channels `<layer>.<pass>.<channel>` (e.g. `ViewLayer.Combined.R`, `ViewLayer.Depth.Z`). Rows in
the file run top to bottom, as in every image here.

OpenImageIO ships with Blender (and is in requirements.txt for plain Python); it is imported on
first use, so importing this module costs nothing.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np


def _oiio():
    import OpenImageIO as oiio
    return oiio


def read_channels(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Every channel of every part of an EXR: full channel name -> (H, W) float32."""
    oiio = _oiio()
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise OSError(f"{path}: cannot read: {oiio.geterror()}")
    channels: dict[str, np.ndarray] = {}
    try:
        subimage = 0
        while inp.seek_subimage(subimage, 0):
            spec = inp.spec()
            pixels = inp.read_image(subimage, 0, 0, spec.nchannels, "float")
            if pixels is None:
                raise OSError(f"{path}: cannot read part {subimage}: {inp.geterror()}")
            pixels = np.asarray(pixels, np.float32).reshape(spec.height, spec.width, spec.nchannels)
            for index, name in enumerate(spec.channelnames):
                channels[name] = pixels[..., index]
            subimage += 1
    finally:
        inp.close()
    return channels


def find_pass(channels: dict[str, np.ndarray], layer: str, name: str,
              components: str) -> np.ndarray | None:
    """The pass `<layer>.<name>` as (H, W, len(components)), or None if any channel is missing."""
    planes = [channels.get(f"{layer}.{name}.{c}") for c in components]
    if any(p is None for p in planes):
        return None
    return np.stack(planes, axis=-1)


def append_layers(path: str | os.PathLike, parts: dict[str, tuple[str, np.ndarray]]) -> None:
    """Rewrite the EXR at `path` with extra parts, keeping every existing part as it was
    (channels, pixels, compression and metadata); the file is replaced atomically.

    parts: part name (`<layer>.<pass>`) -> (channel letters such as "RGBA" or "Z", float32
    pixels (H, W, len(letters))). A part of the same name is replaced.
    """
    oiio = _oiio()
    path = Path(path)
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise OSError(f"{path}: cannot read: {oiio.geterror()}")
    existing: list[tuple[object, np.ndarray]] = []
    try:
        subimage = 0
        while inp.seek_subimage(subimage, 0):
            spec = inp.spec()
            name = spec.getattribute("name") or spec.getattribute("oiio:subimagename")
            pixels = inp.read_image(subimage, 0, 0, spec.nchannels, spec.format)
            if pixels is None:
                raise OSError(f"{path}: cannot read part {subimage}: {inp.geterror()}")
            if name not in parts:
                existing.append((oiio.ImageSpec(spec), np.asarray(pixels)))
            subimage += 1
    finally:
        inp.close()
    if not existing:
        raise OSError(f"{path}: no image parts")
    template = existing[-1][0]
    compression = template.getattribute("compression") or "zip"
    specs, images = [spec for spec, _ in existing], [pixels for _, pixels in existing]
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
        specs.append(spec)
        images.append(pixels)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}.exr")
    out = oiio.ImageOutput.create(str(tmp))
    if out is None or not out.open(str(tmp), specs):
        raise OSError(f"{path}: cannot write: {oiio.geterror()}")
    try:
        for index, (spec, pixels) in enumerate(zip(specs, images)):
            if index and not out.open(str(tmp), spec, "AppendSubimage"):
                raise OSError(f"{path}: cannot write part {index}: {out.geterror()}")
            if not out.write_image(pixels):
                raise OSError(f"{path}: cannot write part {index}: {out.geterror()}")
    except BaseException:
        out.close()
        tmp.unlink(missing_ok=True)
        raise
    out.close()
    os.replace(tmp, path)


def write_channels(path: str | os.PathLike, channels: dict[str, np.ndarray], *,
                   compression: str = "none") -> None:
    """Write (H, W) float32 planes as one uncompressed single-part EXR with those channel
    names (how Blender's `RenderResult.load_from_file` takes a whole render result)."""
    oiio = _oiio()
    names = list(channels)
    pixels = np.ascontiguousarray(np.stack([channels[n] for n in names], axis=-1), np.float32)
    height, width = pixels.shape[:2]
    spec = oiio.ImageSpec(width, height, len(names), "float")
    spec.channelnames = tuple(names)
    spec.attribute("compression", compression)
    out = oiio.ImageOutput.create(str(path))
    if out is None or not out.open(str(path), spec):
        raise OSError(f"{path}: cannot write: {oiio.geterror()}")
    try:
        if not out.write_image(pixels):
            raise OSError(f"{path}: cannot write: {out.geterror()}")
    finally:
        out.close()
