"""The SuperSplat / PlayCanvas compressed `.ply` (read only).

Layout (as written by PlayCanvas splat-transform / SuperSplat and read by the PlayCanvas engine):
- element `chunk`, one row per 256 splats: float `min_x min_y min_z max_x max_y max_z`,
  `min_scale_x.. max_scale_z` (log scales) and, in newer files, `min_r min_g min_b max_r max_g max_b`.
- element `vertex`, one row per splat, four uint32:
  `packed_position`  x:11 | y:10 | z:11 bits (x highest), unorm, lerped between the chunk's min/max;
  `packed_rotation`  2 bits: index of the largest |component| of (rot_0..rot_3) = (w, x, y, z),
                     made positive; then the other three in order, 10 bits each, as
                     (v / 1023 - 0.5) * sqrt(2); the largest is sqrt(1 - a^2 - b^2 - c^2);
  `packed_scale`     11:10:11 like the position, lerped between the chunk's log-scale min/max;
  `packed_color`     r:8 g:8 b:8 opacity:8 (r highest), unorm; r,g,b are `0.5 + SH_C0 * f_dc`
                     (lerped between the chunk's colour min/max when the chunk has them),
                     the last byte is the opacity itself (sigmoid of the logit).
- optional element `sh`: uchar `f_rest_0..` (9, 24 or 45, channel-major like the standard ply),
  quantised as trunc((v / 8 + 0.5) * 256), decoded at the bucket centre (q + 0.5) / 256 with
  0 and 255 pinned to the ends of the [-4, 4] range (as splat-transform's reader does).
Decoding runs in float64 then rounds to float32, so values match the reference decoders.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from ..gaussians import Gaussians, logit
from ..sh import dc_from_colour
from ..formats_common.errors import SplatFileError, check_decoded
from ..formats_common.limits import check_gaussian_count
from ..formats_common.ply_sh import F_REST_COUNTS, f_rest_names, sh_from_file_layout
from ..formats_common.plyfile import PlyHeader, PlyTable, check_finite, read_elements, read_header

__all__ = ["load", "CHUNK_SIZE"]

CHUNK_SIZE = 256  # splats per chunk row
OPACITY_LOGIT_LIMIT = 40.0  # opacity byte 0 or 255 maps here, as the PlayCanvas engine does

CHUNK_POSITION = ("min_x", "min_y", "min_z", "max_x", "max_y", "max_z")
CHUNK_SCALE = ("min_scale_x", "min_scale_y", "min_scale_z", "max_scale_x", "max_scale_y", "max_scale_z")
CHUNK_COLOR = ("min_r", "min_g", "min_b", "max_r", "max_g", "max_b")
PACKED = ("packed_position", "packed_rotation", "packed_scale", "packed_color")


def _unorm(bits: np.ndarray, shift: int, width: int) -> np.ndarray:
    """An unsigned `width`-bit field at `shift` as a float64 in [0, 1]."""
    mask = (1 << width) - 1
    return ((bits >> np.uint32(shift)) & np.uint32(mask)).astype(np.float64) / mask


def _unpack_11_10_11(bits: np.ndarray) -> np.ndarray:
    return np.stack([_unorm(bits, 21, 11), _unorm(bits, 11, 10), _unorm(bits, 0, 11)], axis=1)


def _lerp_per_chunk(t: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """t (N, k) in [0, 1] between per-chunk bounds lo, hi (C, k); splat i is in chunk i // 256."""
    lo = np.repeat(lo.astype(np.float64), CHUNK_SIZE, axis=0)[: len(t)]
    hi = np.repeat(hi.astype(np.float64), CHUNK_SIZE, axis=0)[: len(t)]
    return lo * (1.0 - t) + hi * t


def _unpack_rotation(bits: np.ndarray) -> np.ndarray:
    """Smallest-three quaternions -> (N, 4) in file order rot_0..rot_3 (w, x, y, z)."""
    small = np.stack([_unorm(bits, 20, 10), _unorm(bits, 10, 10), _unorm(bits, 0, 10)], axis=1)
    small = (small - 0.5) * math.sqrt(2.0)
    largest = np.sqrt(np.maximum(0.0, 1.0 - np.einsum("ij,ij->i", small, small)))
    which = (bits >> np.uint32(30)).astype(np.intp)
    # Slot k holds small[k] before the largest and small[k - 1] after it.
    slot = np.arange(4)
    pick = np.minimum(slot - (slot > which[:, None]), 2)
    quat = np.take_along_axis(small, pick, axis=1)
    quat[np.arange(len(bits)), which] = largest
    return quat


def _unpack_color(bits: np.ndarray, chunk: PlyTable, has_color_bounds: bool) -> tuple[np.ndarray, np.ndarray]:
    """-> (f_dc (N,3), opacity logits (N,)) as float64."""
    rgb = np.stack([_unorm(bits, 24, 8), _unorm(bits, 16, 8), _unorm(bits, 8, 8)], axis=1)
    if has_color_bounds:
        bounds = chunk.gather(CHUNK_COLOR, np.float64)
        rgb = _lerp_per_chunk(rgb, bounds[:, :3], bounds[:, 3:])
    alpha = _unorm(bits, 0, 8)
    with np.errstate(divide="ignore"):
        logits = np.where(alpha <= 0.0, -OPACITY_LOGIT_LIMIT,
                          np.where(alpha >= 1.0, OPACITY_LOGIT_LIMIT, logit(alpha)))
    return dc_from_colour(rgb), logits


def _decode_sh(path: Path, table: PlyTable, n: int) -> np.ndarray:
    """The `sh` element's quantised f_rest bytes -> (N, 3*(K-1)) float32, channel-major."""
    count = len(table.element.properties)
    if count not in F_REST_COUNTS or count == 0:
        raise SplatFileError(path, f"unsupported f_rest count {count} in element 'sh': expected 9, 24 or 45")
    if len(table) != n:
        raise SplatFileError(path, f"element 'sh' has {len(table)} rows, 'vertex' has {n}")
    q = table.gather(f_rest_names(count), np.float64)
    unit = np.where(q <= 0, 0.0, np.where(q >= 255, 1.0, (q + 0.5) / 256.0))
    return ((unit - 0.5) * 8.0).astype(np.float32)


def _check_layout(path: Path, chunk: PlyTable, vertex: PlyTable) -> bool:
    """Validate the chunk/vertex schema; returns whether the chunks carry colour bounds."""
    for table, names in ((chunk, CHUNK_POSITION + CHUNK_SCALE), (vertex, PACKED)):
        missing = table.missing(names)
        if missing:
            raise SplatFileError(path, f"missing required property {missing[0]!r} in element "
                                       f"{table.element.name!r} of a compressed ply")
    expected = -(-len(vertex) // CHUNK_SIZE)
    if len(chunk) != expected:
        raise SplatFileError(path, f"compressed ply has {len(chunk)} chunk rows; {len(vertex)} splats "
                                   f"need {expected}")
    return not chunk.missing(CHUNK_COLOR)


def load(path: str | os.PathLike, header: PlyHeader | None = None) -> Gaussians:
    """Decode a SuperSplat compressed `.ply` into `Gaussians`."""
    path = Path(path)
    header = header if header is not None else read_header(path)
    if header.element("vertex") is None:
        raise SplatFileError(path, "missing element 'vertex' in a compressed ply")
    wanted = ["chunk", "vertex"] + (["sh"] if header.element("sh") is not None else [])
    tables = read_elements(path, header, wanted,
                           check_rows=lambda p, rows: check_gaussian_count(p, header.element("vertex").count))
    chunk, vertex = tables["chunk"], tables["vertex"]
    has_color_bounds = _check_layout(path, chunk, vertex)
    bounds = chunk.gather(CHUNK_POSITION + CHUNK_SCALE, np.float64)
    check_finite(path, bounds, CHUNK_POSITION + CHUNK_SCALE)
    packed = vertex.gather(PACKED, np.uint32)

    means = _lerp_per_chunk(_unpack_11_10_11(packed[:, 0]), bounds[:, 0:3], bounds[:, 3:6])
    log_scales = _lerp_per_chunk(_unpack_11_10_11(packed[:, 2]), bounds[:, 6:9], bounds[:, 9:12])
    dc, logits = _unpack_color(packed[:, 3], chunk, has_color_bounds)
    rest = _decode_sh(path, tables["sh"], len(vertex)) if "sh" in tables else np.zeros((len(vertex), 0), np.float32)
    gaussians = Gaussians(means, log_scales, _unpack_rotation(packed[:, 1]), logits,
                          sh_from_file_layout(dc.astype(np.float32), rest))
    return check_decoded(path, gaussians)  # e.g. non-finite colour bounds
