"""Blender's splat attributes <-> `Gaussians`: the one place that knows Blender 5.3's convention.

Blender 5.3 keeps a Gaussian splat cloud as a point cloud of type 'GAUSSIAN_SPLAT' with these
point-domain attributes (written by its PLY and SPZ importers, `io/common/intern/gsplat.cc`):

    position        FLOAT_VECTOR  centre, object space                  = our `means`
    scale           FLOAT_VECTOR  linear standard deviations            = exp(our `log_scales`)
    rotation        QUATERNION    w, x, y, z                            = our `quats`, as they are
    radiance:base   FLOAT4        x, y, z: the SH DC coefficients as the .ply stores them
                                  (= our `sh[:, 0]`); w: opacity after the sigmoid
                                  (= sigmoid(our `opacity_logits`))
    radiance:sh_j   FLOAT_VECTOR  the higher SH coefficients, one per attribute, RGB, numbered
                                  across the bands in the 3DGS order: sh_0..2 band 1, sh_3..7
                                  band 2, sh_8..14 band 3, sh_15..23 band 4 (= our `sh[:, j + 1]`)

Where the two disagree, this module says which one it follows:
- SH degree: Blender holds up to degree 4, the renderer (and `Gaussians`) stops at 3. Degree 4
  reads as bands 0-3 with a warning; an incomplete band is dropped with a warning.
- opacity: float32 sigmoid saturates (a logit above about 16.6 stores 1.0). Reading clamps the
  opacity to [2^-126, 1 - 2^-24] before the logit, so every value maps to a finite logit whose
  opacity is the stored one to float32 rounding (the renderer caps alpha at 0.99 anyway).
- scale: a zero scale (or a negative one: the Gaussian is the same) reads as |scale| floored at
  2^-126, so the log stays finite.
- colour space and antialiasing: Blender's attributes record neither; the values are taken as
  they are (display-sRGB SH as trained, the standard, non-antialiased 3DGS model), which is what
  Blender's importers assume too.
- axes: none here. Blender's PLY importer keeps the file's data and puts its axis change into
  the object matrix, its SPZ importer bakes it into the data; either way the object's matrix
  applied to these object-space values gives the world-space Gaussians, as for our objects.

Missing or mistyped attributes (not numbers: object, dict, structured or string arrays; or of
another shape than (N, width) or flat) raise `BlenderSplatError` naming the attribute; a point
with a NaN or Inf in any value it is read from is dropped and counted (`Conversion.dropped`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from ..gaussians import Gaussians, sh_count

POSITION = "position"
SCALE = "scale"
ROTATION = "rotation"
BASE = "radiance:base"
SH_PREFIX = "radiance:sh_"
MAX_DEGREE = 4          # what Blender's splats can hold
RENDER_MAX_DEGREE = 3   # what `Gaussians` (and the renderer) hold

# name -> (Blender attribute data type, values per point)
REQUIRED = {
    POSITION: ("FLOAT_VECTOR", 3),
    SCALE: ("FLOAT_VECTOR", 3),
    ROTATION: ("QUATERNION", 4),
    BASE: ("FLOAT4", 4),
}
SH_TYPE = ("FLOAT_VECTOR", 3)

_OPACITY_MIN = float(np.float32(2.0 ** -126))
_OPACITY_MAX = float(np.float32(1.0) - np.float32(2.0 ** -24))
_SCALE_MIN = float(np.float32(2.0 ** -126))
_SCALE_MAX = float(np.finfo(np.float32).max)  # a log-scale above ~88.7 would overflow float32


class BlenderSplatError(ValueError):
    """Data that does not hold Blender splats (a required attribute missing or mistyped)."""


def sh_name(j: int) -> str:
    """The name of Blender's j-th higher SH coefficient (our coefficient j + 1)."""
    return f"{SH_PREFIX}{j}"


def sh_names(degree: int) -> tuple[str, ...]:
    """Blender's higher-SH attribute names for an SH degree (0..4): (degree+1)^2 - 1 of them."""
    if not 0 <= degree <= MAX_DEGREE:
        raise ValueError(f"Blender's splats hold SH degree 0..{MAX_DEGREE}, got {degree}")
    return tuple(sh_name(j) for j in range((degree + 1) ** 2 - 1))


def degree_of(present: set[str] | frozenset[str]) -> tuple[int, list[str]]:
    """The SH degree whose `radiance:sh_*` attributes are all in `present` (the highest complete
    band), and warnings about bands left out (degree 4, or an incomplete band)."""
    degree = 0
    for candidate in range(1, MAX_DEGREE + 1):
        if all(name in present for name in sh_names(candidate)):
            degree = candidate
        else:
            break
    warnings = []
    extra = sorted(n for n in present if n.startswith(SH_PREFIX) and n not in sh_names(degree))
    if extra:
        warnings.append(f"SH attributes {', '.join(extra)} do not complete a band: left out")
    if degree > RENDER_MAX_DEGREE:
        warnings.append(f"SH degree {degree} read as degree {RENDER_MAX_DEGREE}: bands beyond "
                        f"{RENDER_MAX_DEGREE} are left out (the renderer stops at degree 3)")
    return degree, warnings


@dataclass
class Conversion:
    """What `gaussians_from_attributes` made, and what it had to leave out."""

    gaussians: Gaussians
    dropped: int = 0                  # points with a non-finite value, left out
    kept: np.ndarray | None = None    # (N,) bool over the input points, None when all kept
    source_degree: int = 0            # the SH degree the attributes held (up to 4)
    warnings: list[str] = field(default_factory=list)


def _checked(arrays: Mapping[str, np.ndarray], name: str, width: int, n: int | None,
             source: str) -> np.ndarray:
    """Attribute `name` as float32 (n, width): numbers only (no object, structured, string or
    complex arrays), flat (n * width,) or (n, width); else a BlenderSplatError naming it."""
    if name not in arrays:
        raise BlenderSplatError(f"{source}: no {name!r} attribute: not Blender splat data")
    what = f"{source}: attribute {name!r}"
    try:
        array = np.asarray(arrays[name])
    except (TypeError, ValueError) as e:  # ragged nested lists, objects numpy cannot hold
        raise BlenderSplatError(f"{what} is not an array of numbers: {e}") from None
    if array.dtype.kind not in "fiu":  # object, dict, structured (V), str (U, S), bool, complex
        raise BlenderSplatError(f"{what} holds {array.dtype} values, expected numbers (float32)")
    if n is None:
        n = array.size // width
    if array.shape not in ((n * width,), (n, width)):
        raise BlenderSplatError(f"{what} has shape {array.shape}, expected ({n}, {width}) or "
                                f"({n * width},)")
    with np.errstate(over="ignore", invalid="ignore"):  # beyond float32: inf, dropped as non-finite
        return array.astype(np.float32).reshape(n, width)


def gaussians_from_attributes(arrays: Mapping[str, np.ndarray], *,
                              source: str = "Blender splats") -> Conversion:
    """`Gaussians` (object space) from Blender's splat attributes, given as float32 arrays by
    name (flat or (N, width)). `source` names the data in errors."""
    means = _checked(arrays, POSITION, 3, None, source)
    n = len(means)
    scales = _checked(arrays, SCALE, 3, n, source)
    quats = _checked(arrays, ROTATION, 4, n, source)
    base = _checked(arrays, BASE, 4, n, source)
    source_degree, warnings = degree_of(frozenset(arrays))
    degree = min(source_degree, RENDER_MAX_DEGREE)
    sh = np.empty((n, sh_count(degree), 3), np.float32)
    sh[:, 0] = base[:, :3]
    for j, name in enumerate(sh_names(degree)):
        sh[:, j + 1] = _checked(arrays, name, 3, n, source)

    finite = (np.isfinite(means).all(1) & np.isfinite(scales).all(1) & np.isfinite(quats).all(1)
              & np.isfinite(base).all(1) & np.isfinite(sh).all((1, 2)))
    dropped = int(n - np.count_nonzero(finite))
    kept = None
    if dropped:
        kept = finite
        means, scales, quats, base, sh = (a[finite] for a in (means, scales, quats, base, sh))
        warnings.append(f"{source}: {dropped} of {n} splats hold NaN or Inf and were left out")

    log_scales = np.log(np.maximum(np.abs(scales.astype(np.float64)), _SCALE_MIN))
    gaussians = Gaussians(means, log_scales, quats, opacity_logits(base[:, 3]), sh)
    return Conversion(gaussians, dropped, kept, source_degree, warnings)


def opacity_logits(opacity: np.ndarray) -> np.ndarray:
    """Logits of Blender's opacities (radiance:base w), clamped so that 0 and 1 stay finite."""
    clipped = np.clip(np.asarray(opacity, np.float64), _OPACITY_MIN, _OPACITY_MAX)
    return (np.log(clipped) - np.log1p(-clipped)).astype(np.float32)


def attributes_from_gaussians(gaussians: Gaussians) -> dict[str, np.ndarray]:
    """Blender's splat attributes for `gaussians` (object space): name -> float32 (N, width)
    arrays, `radiance:sh_*` for the Gaussians' SH degree. Raises ValueError on NaN or Inf."""
    bad = gaussians.non_finite()
    if bad is not None:
        raise ValueError(f"Gaussians.{bad} holds NaN or Inf")
    n = len(gaussians)
    base = np.empty((n, 4), np.float32)
    base[:, :3] = gaussians.sh[:, 0]
    logits = gaussians.opacity_logits.astype(np.float64)
    base[:, 3] = 0.5 * (1.0 + np.tanh(0.5 * logits))  # sigmoid without overflow
    out = {
        POSITION: gaussians.means,
        SCALE: np.minimum(np.exp(gaussians.log_scales.astype(np.float64)), _SCALE_MAX).astype(np.float32),
        ROTATION: gaussians.quats,
        BASE: base,
    }
    for j, name in enumerate(sh_names(gaussians.degree)):
        out[name] = np.ascontiguousarray(gaussians.sh[:, j + 1])
    return out
