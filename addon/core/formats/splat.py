"""antimatter15 `.splat`: a headerless array of 32-byte little-endian records, one per Gaussian.

Layout (verified against antimatter15/splat `convert.py` (writer) and `main.js` (reader)):

    bytes  0..11  position   3 x float32, the scene frame of the 3DGS .ply (no axis change)
    bytes 12..23  scale      3 x float32, *linear* standard deviations (exp of the .ply scale_*)
    bytes 24..27  RGBA       4 x uint8: RGB = (0.5 + SH_C0 * f_dc) * 255, A = sigmoid(opacity) * 255
    bytes 28..31  rotation   4 x uint8, quaternion w, x, y, z as q * 128 + 128 (viewer: (b - 128) / 128)

Only the SH DC term fits: higher SH bands are dropped on write (a `.splat` shows view-independent
colour), and a loaded file has SH degree 0. Records are written in the order given; antimatter15's
converter sorts by size * opacity for progressive loading, which no reader relies on.

Quantisation (write then read; bounds hold for values inside each range):
    position, scale    float32 (the loaded log_scale is the float32 whose exp gives the stored
                       scale back exactly where one exists; otherwise within one float32 step)
    DC colour          0.5 + SH_C0 * f_dc rounded to k/255, clipped to [0, 1]: error <= 0.5/255
    opacity            sigmoid(logit) rounded to k/255: error <= 0.5/255. Byte 0 and 255 decode to
                       0.25/255 and 1 - 0.25/255 (the middle of their rounding interval) so that
                       logits stay finite and re-encode to the same byte.
    rotation           the normalised quaternion rounded to k/128 per component (q = 1 clips to
                       127/128): error <= 1/128 per component. Decoded quaternions are returned as
                       stored, unnormalised (norm within 1/64 of 1 in any sane file, as the viewer
                       uses them); the writer keeps such already-quantised quaternions as they
                       are, so that read -> write reproduces the stored bytes exactly.
The antimatter15 converter truncates instead of rounding; its files read the same way.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..gaussians import Gaussians, log_scales_of, logit, scales_of, sigmoid
from ..sh import dc_colour, dc_from_colour
from ..atomic import atomic_write
from ..formats_common.errors import SplatFileError, check_savable, os_errors
from ..formats_common.limits import check_gaussian_count

__all__ = ["load", "save", "RECORD"]


RECORD = np.dtype([("position", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4), ("rot", "u1", 4)])
assert RECORD.itemsize == 32

# Byte 0/255 alpha decodes to the middle of its rounding interval, not to 0/1 (infinite logits).
_ALPHA_EDGE = 0.25 / 255.0
# Quaternions decoded from a file (on the k/128 lattice) and this close to unit norm are written back
# as they are: normalising them would move them by about one step and make every re-save drift.
# Rounded unit quaternions decode to norms within 1/128 of 1; truncating writers within 1/64.
_QUAT_UNIT_TOLERANCE = 1.0 / 64.0


def _first_bad(mask: np.ndarray) -> int:
    return int(np.flatnonzero(mask.reshape(len(mask), -1).any(axis=1))[0])


def _exp32(log_scales: np.ndarray) -> np.ndarray:
    """float32 exp as the writer computes it (in float64, rounded once)."""
    with np.errstate(over="ignore"):  # the cast to float32 overflows as exp may
        return scales_of(log_scales).astype(np.float32)


def _log32(scale: np.ndarray) -> np.ndarray:
    """float32 log of positive float32 scales, chosen among the neighbours of the rounded log so
    that the writer's exp gives the stored scale back bit for bit wherever some float32 can (where
    logs are coarser than the scales none can, and re-saving settles after one save)."""
    log = log_scales_of(scale).astype(np.float32)
    best, found = log.copy(), _exp32(log) == scale
    for direction in (np.inf, -np.inf):
        candidate = log
        for _ in range(2):
            candidate = np.nextafter(candidate, np.float32(direction))
            hit = ~found & (_exp32(candidate) == scale)
            best[hit], found = candidate[hit], found | hit
    return best


def decode_alpha(alpha: np.ndarray) -> np.ndarray:
    """uint8 opacity (round(sigmoid * 255)) -> float32 logit, finite at the ends."""
    p = np.clip(alpha.astype(np.float64) / 255.0, _ALPHA_EDGE, 1.0 - _ALPHA_EDGE)
    return logit(p).astype(np.float32)


def encode_alpha(logits: np.ndarray) -> np.ndarray:
    """float logit -> uint8 round(sigmoid * 255)."""
    opacity = sigmoid(logits)
    return np.clip(np.rint(opacity * 255.0), 0, 255).astype(np.uint8)


def load(path: str | os.PathLike) -> Gaussians:
    """Read a `.splat` file (SH degree 0)."""
    path = Path(path)
    with os_errors(path, "cannot read file"):
        size = path.stat().st_size
        check_gaussian_count(path, size // RECORD.itemsize)
        data = path.read_bytes()
    if len(data) % RECORD.itemsize:
        raise SplatFileError(path, f"size {len(data)} bytes is not a multiple of the 32-byte .splat "
                                   f"record (truncated, or not a .splat file)")
    rec = np.frombuffer(data, dtype=RECORD)
    n = len(rec)
    position = rec["position"].astype(np.float32)
    scale = rec["scale"].astype(np.float32)
    for name, values in (("position", position), ("scale", scale)):
        bad = ~np.isfinite(values)
        if bad.any():
            raise SplatFileError(path, f"non-finite {name} in splat {_first_bad(bad)} of {n}")
    if (scale < 0).any():
        raise SplatFileError(path, f"negative scale in splat {_first_bad(scale < 0)} of {n}")
    # A zero scale is a legal degenerate splat; its log is clamped to the smallest normal float.
    log_scales = _log32(np.maximum(scale, np.finfo(np.float32).tiny))

    rgba = rec["rgba"]
    sh = dc_from_colour(rgba[:, :3].astype(np.float32) / 255.0).reshape(n, 1, 3)
    quats = (rec["rot"].astype(np.float32) - 128.0) / 128.0  # w, x, y, z as the viewer decodes
    return Gaussians(position, log_scales, quats, decode_alpha(rgba[:, 3]), sh)


def encode(gaussians: Gaussians, path: str | os.PathLike = "<memory>") -> np.ndarray:
    """The `.splat` records for `gaussians` (a structured array of RECORD)."""
    check_savable(path, gaussians)
    n = len(gaussians)
    rec = np.zeros(n, dtype=RECORD)
    rec["position"] = gaussians.means
    scale = _exp32(gaussians.log_scales)
    if not np.isfinite(scale).all():
        raise SplatFileError(path, f"cannot write: exp(log_scale) overflows float32 in splat "
                                   f"{_first_bad(~np.isfinite(scale))}")
    rec["scale"] = scale

    colour = dc_colour(gaussians.sh[:, 0, :].astype(np.float64))
    rec["rgba"][:, :3] = np.clip(np.rint(colour * 255.0), 0, 255)
    rec["rgba"][:, 3] = encode_alpha(gaussians.opacity_logits)

    q = gaussians.quats.astype(np.float64)
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    q = np.where(norm == 0, np.array([1.0, 0.0, 0.0, 0.0]), q)  # zero means identity (see Gaussians)
    stored = np.all(np.abs(q * 128.0 - np.rint(q * 128.0)) < 1e-4, axis=1, keepdims=True)
    keep = stored & (np.abs(norm - 1.0) <= _QUAT_UNIT_TOLERANCE)
    q = np.where(keep | (norm == 0), q, q / np.where(norm > 0, norm, 1.0))
    rec["rot"] = np.clip(np.rint(q * 128.0 + 128.0), 0, 255)
    return rec


def save(gaussians: Gaussians, path: str | os.PathLike) -> None:
    """Write `gaussians` as `.splat` (SH bands above the DC term are dropped)."""
    path = Path(path)
    data = encode(gaussians, path).tobytes()
    with os_errors(path), atomic_write(path) as f:
        f.write(data)
