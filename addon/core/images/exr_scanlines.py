"""Reading OpenEXR scanline files in NumPy alone (no OpenImageIO, no bpy).

Blender's own Python (official builds bundle OpenImageIO, distributions' builds do not) can
always write an EXR (`Image.save_render`, the render cache); this reads the ones Blender writes
for the render integration: scanline images, single- or multi-part, HALF / FLOAT / UINT
channels, compression NONE, ZIPS or ZIP (zlib is in Python's standard library). Anything else
(tiles, deep data, PIZ, DWA...) raises `ValueError` naming the file and what it holds.

`read_channels(path)` returns every channel of every part, full channel name -> (H, W) float32,
rows top to bottom, as `exr.read_channels` (OpenImageIO) does (uncompressed FLOAT channels as
read-only views of the file's bytes, with row strides: copy them to write). `mapped=True` maps
the file instead of reading it: the views then read the file itself (1 ms less for 18 MB in
/dev/shm), so it must be a private file that nothing rewrites while they live (delete it once
read: on POSIX the mapping keeps its pages).
"""

from __future__ import annotations

import mmap
import os
import struct
import zlib

import numpy as np

_MAGIC = 20000630
_TYPES = {0: np.dtype("<u4"), 1: np.dtype("<f2"), 2: np.dtype("<f4")}
_LINES_PER_CHUNK = {0: 1, 2: 1, 3: 16}    # NONE, ZIPS, ZIP
_COMPRESSION_NAMES = {0: "NONE", 1: "RLE", 2: "ZIPS", 3: "ZIP", 4: "PIZ", 5: "PXR24", 6: "B44",
                      7: "B44A", 8: "DWAA", 9: "DWAB"}


def _cstring(data: bytes, pos: int) -> tuple[str, int]:
    end = data.find(b"\0", pos)
    if end < 0:
        raise ValueError("an EXR header string runs past the end of the file")
    return data[pos:end].decode("latin-1"), end + 1


def _header(data: bytes, pos: int, path) -> tuple[dict, int]:
    """One header: attribute name -> (type, raw bytes); returns the position after it."""
    attributes = {}
    while True:
        name, pos = _cstring(data, pos)
        if not name:
            return attributes, pos
        kind, pos = _cstring(data, pos)
        (size,) = struct.unpack_from("<i", data, pos)
        pos += 4
        if size < 0 or pos + size > len(data):
            raise ValueError(f"{path}: not a valid EXR file (attribute {name!r} runs past the end)")
        attributes[name] = (kind, data[pos:pos + size])
        pos += size


def _channels(raw: bytes) -> list[tuple[str, int, int, int]]:
    """chlist: (name, pixel type, x sampling, y sampling), in the file's (sorted) order."""
    out, pos = [], 0
    while pos < len(raw) and raw[pos] != 0:
        name, pos = _cstring(raw, pos)
        pixel_type, _linear, xs, ys = struct.unpack_from("<iB3xii", raw, pos)
        pos += 16
        out.append((name, pixel_type, xs, ys))
    return out


def _undo_zip(chunk: bytes, size: int) -> bytes:
    """ZIP/ZIPS: zlib, then a byte-delta predictor over bytes split into two interleaved halves."""
    t = np.frombuffer(zlib.decompress(chunk), np.uint8)
    if t.size != size:
        raise ValueError("a compressed block has the wrong size")
    t = (np.cumsum(t.astype(np.int64) - 128) + 128) & 0xFF   # t[i] = t[i-1] + d[i] - 128
    t = t.astype(np.uint8)
    out = np.empty(size, np.uint8)
    half = (size + 1) // 2
    out[0::2] = t[:half]
    out[1::2] = t[half:]
    return out.tobytes()


def _uncompressed_view(data: bytes, multipart: bool, offsets: np.ndarray, y0: int,
                       height: int, row_dtype: np.dtype) -> np.ndarray | None:
    """Uncompressed scanlines stored one after another in increasing y (as Blender writes
    them): the rows as one view of the file's bytes, no per-line work; None otherwise."""
    head = 12 if multipart else 8
    stride = head + row_dtype.itemsize
    start = int(offsets[0])
    if len(offsets) != height or start + stride * height > len(data) or \
            not np.array_equal(offsets, start + stride * np.arange(height, dtype=np.uint64)):
        return None
    chunk = np.dtype([("head", "<i4", (head // 4,)), ("row", row_dtype)])
    chunks = np.frombuffer(data, chunk, height, start)
    ys = chunks["head"][:, -2]
    sizes = chunks["head"][:, -1]
    if not (np.array_equal(ys, y0 + np.arange(height)) and (sizes == row_dtype.itemsize).all()):
        return None
    return chunks["row"]


def read_channels(path: str | os.PathLike, *, mapped: bool = False) -> dict[str, np.ndarray]:
    """Every channel of every part: full channel name -> (H, W) float32, rows top to bottom."""
    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        data = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) if mapped and size else f.read()
    if len(data) < 8 or struct.unpack_from("<i", data, 0)[0] != _MAGIC:
        raise ValueError(f"{path}: not an OpenEXR file")
    flags = struct.unpack_from("<I", data, 4)[0] >> 8
    if flags & 0x2 or flags & 0x8:
        raise ValueError(f"{path}: tiled or deep EXR files are not read here")
    multipart = bool(flags & 0x10)
    headers, pos = [], 8
    while True:
        header, pos = _header(data, pos, path)
        headers.append(header)
        if not multipart or data[pos] == 0:
            break
    if multipart:
        pos += 1  # the empty header that ends the list
    parts = []
    for header in headers:
        compression = header["compression"][1][0]
        if compression not in _LINES_PER_CHUNK:
            raise ValueError(f"{path}: EXR compression {_COMPRESSION_NAMES.get(compression)} is "
                             f"not read here (NONE, ZIPS or ZIP are)")
        if "type" in header and not header["type"][1].startswith(b"scanlineimage"):
            raise ValueError(f"{path}: only scanline EXR parts are read here")
        x0, y0, x1, y1 = struct.unpack("<4i", header["dataWindow"][1])
        width, height = x1 - x0 + 1, y1 - y0 + 1
        channels = _channels(header["channels"][1])
        if any(xs != 1 or ys != 1 for _, _, xs, ys in channels):
            raise ValueError(f"{path}: subsampled EXR channels are not read here")
        lines = _LINES_PER_CHUNK[compression]
        chunks = (height + lines - 1) // lines
        offsets = np.frombuffer(data, "<u8", chunks, pos)
        pos += 8 * chunks
        parts.append((compression, y0, width, height, channels, lines, offsets))
    out: dict[str, np.ndarray] = {}
    for index, (compression, y0, width, height, channels, lines, offsets) in enumerate(parts):
        row_dtype = np.dtype([(f"c{i}", _TYPES[t], (width,)) for i, (_, t, _, _) in enumerate(channels)])
        image = _uncompressed_view(data, multipart, offsets, y0, height, row_dtype) \
            if compression == 0 else None
        if image is not None:  # views of the file's bytes (FLOAT), no copy
            for i, (name, _, _, _) in enumerate(channels):
                out[name] = image[f"c{i}"].astype(np.float32, copy=False)
            continue
        image = np.empty(height, row_dtype)
        for offset in offsets:
            at = int(offset) + (4 if multipart else 0)
            y, size = struct.unpack_from("<ii", data, at)
            first = y - y0
            count = min(lines, height - first)
            chunk = data[at + 8:at + 8 + size]
            expected = count * row_dtype.itemsize
            if size != expected:
                if compression == 0:
                    raise ValueError(f"{path}: a scanline block has the wrong size")
                chunk = _undo_zip(chunk, expected)
            image[first:first + count] = np.frombuffer(chunk, row_dtype, count)
        for i, (name, _, _, _) in enumerate(channels):
            out[name] = np.ascontiguousarray(image[f"c{i}"], np.float32)
    return out
