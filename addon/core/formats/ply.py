"""The standard 3DGS `.ply` file (Inria layout), read and written with numpy.

A splat file is a PLY file whose `vertex` element carries, per Gaussian, `x y z`, `f_dc_0..2`,
`f_rest_*` (0, 9, 24 or 45 of them, stored channel-major), `opacity` (a logit), `scale_0..2`
(natural-log scales) and `rot_0..3` (quaternion w, x, y, z). Anything else (normals, extra
attributes, other elements after `vertex`) is ignored. A file with a `chunk` element is the
SuperSplat compressed layout and goes to `compressed_ply`.

The generic PLY parsing is `plyfile`; every problem is a `SplatFileError` naming the file.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import BinaryIO

import numpy as np

from ..gaussians import Gaussians
from ..atomic import atomic_write
from ..formats_common.errors import SplatFileError, check_savable, os_errors
from ..formats_common.limits import check_gaussian_count
from ..formats_common.ply_sh import F_REST_COUNTS, f_rest_names
from ..formats_common.plyfile import PlyElement, PlyTable, check_finite, read_elements, read_header

__all__ = ["load", "save", "read_header", "property_names"]

_WRITE_ROWS = 1 << 16  # rows per block when saving: bounds the temporary copy

# Per-Gaussian properties of the standard layout, grouped as they map onto `Gaussians`.
MEANS = ("x", "y", "z")
NORMALS = ("nx", "ny", "nz")
DC = ("f_dc_0", "f_dc_1", "f_dc_2")
OPACITY = ("opacity",)
SCALES = ("scale_0", "scale_1", "scale_2")
ROTATION = ("rot_0", "rot_1", "rot_2", "rot_3")
REQUIRED = MEANS + DC + OPACITY + SCALES + ROTATION
_F_REST = re.compile(r"f_rest_(\d+)$")


def _vertex_schema(path: Path, element: PlyElement) -> int:
    """Check the vertex properties from the header alone; returns the f_rest count."""
    if not element.is_fixed_size:
        raise SplatFileError(path, "unsupported list property in element 'vertex'")
    names = set(element.names)
    missing = [n for n in REQUIRED if n not in names]
    if missing:
        raise SplatFileError(path, f"missing required property {missing[0]!r} in element 'vertex'")
    indices = sorted(int(m.group(1)) for n in element.names if (m := _F_REST.match(n)))
    if len(indices) not in F_REST_COUNTS:
        raise SplatFileError(path, f"unsupported f_rest count {len(indices)}: expected 0, 9, 24 or 45 "
                                   f"(SH degree 0..3)")
    if indices != list(range(len(indices))):
        gap = next(i for i, j in enumerate(indices) if i != j)
        raise SplatFileError(path, f"missing required property 'f_rest_{gap}' in element 'vertex'")
    return len(indices)


def _gather_finite(path: Path, table: PlyTable, names: tuple[str, ...] | list[str],
                   out: np.ndarray | None = None) -> np.ndarray:
    values = table.gather(names, out=out)
    check_finite(path, values, names)
    return values


def _gather_sh(path: Path, table: PlyTable, rest_count: int) -> np.ndarray:
    """DC and channel-major f_rest straight into the (N, K, 3) coefficient-major layout."""
    k = rest_count // 3 + 1
    sh = np.empty((len(table), k, 3), np.float32)
    _gather_finite(path, table, DC, out=sh[:, 0, :])
    for channel in range(3):
        names = f_rest_names(rest_count)[channel * (k - 1):(channel + 1) * (k - 1)]
        if names:
            _gather_finite(path, table, names, out=sh[:, 1:, channel])
    return sh


def _gaussians_from_vertices(path: Path, table: PlyTable, rest_count: int) -> Gaussians:
    sh = _gather_sh(path, table, rest_count)
    return Gaussians(
        means=_gather_finite(path, table, MEANS),
        log_scales=_gather_finite(path, table, SCALES),
        quats=_gather_finite(path, table, ROTATION),
        opacity_logits=_gather_finite(path, table, OPACITY)[:, 0],
        sh=sh,
    )


def load(path: str | os.PathLike) -> Gaussians:
    """Read a 3DGS `.ply` (standard or SuperSplat compressed) into `Gaussians`."""
    path = Path(path)
    header = read_header(path)
    if header.element("chunk") is not None:
        from . import compressed_ply
        return compressed_ply.load(path, header)
    vertex = header.element("vertex")
    if vertex is None:
        raise SplatFileError(path, "missing element 'vertex': not a Gaussian splat file")
    rest_count = _vertex_schema(path, vertex)  # before reading: a wrong file fails fast
    table = read_elements(path, header, ["vertex"], check_rows=check_gaussian_count)["vertex"]
    return _gaussians_from_vertices(path, table, rest_count)


def property_names(degree: int) -> list[str]:
    """The standard property order of a written file."""
    rest = f_rest_names(3 * ((degree + 1) ** 2 - 1))
    return [*MEANS, *NORMALS, *DC, *rest, *OPACITY, *SCALES, *ROTATION]


def _header_text(count: int, degree: int) -> bytes:
    lines = ["ply", "format binary_little_endian 1.0", f"element vertex {count}"]
    lines += [f"property float {name}" for name in property_names(degree)]
    lines.append("end_header\n")
    return "\n".join(lines).encode("ascii")


def _rows_block(g: Gaussians, lo: int, hi: int) -> np.ndarray:
    """Rows lo..hi in file order as a little-endian float32 (n, P) matrix."""
    n, k = hi - lo, g.sh.shape[1]
    rest = g.sh[lo:hi, 1:, :].transpose(0, 2, 1).reshape(n, 3 * (k - 1))  # channel-major
    block = np.concatenate([
        g.means[lo:hi], np.zeros((n, 3), np.float32), g.sh[lo:hi, 0, :], rest,
        g.opacity_logits[lo:hi, None], g.log_scales[lo:hi], g.quats[lo:hi],
    ], axis=1)
    return np.ascontiguousarray(block, dtype="<f4")


def _write_body(f: BinaryIO, g: Gaussians) -> None:
    for lo in range(0, len(g), _WRITE_ROWS):
        f.write(memoryview(_rows_block(g, lo, min(len(g), lo + _WRITE_ROWS))).cast("B"))


def save(gaussians: Gaussians, path: str | os.PathLike) -> None:
    """Write the standard binary little-endian 3DGS `.ply`, atomically (temp file + rename)."""
    path = Path(path)
    check_savable(path, gaussians)
    with os_errors(path), atomic_write(path) as f:
        f.write(_header_text(len(gaussians), gaussians.degree))
        _write_body(f, gaussians)
