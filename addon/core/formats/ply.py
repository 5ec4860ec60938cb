"""The standard 3DGS `.ply` file (Inria layout), read and written with numpy.

A splat file is a PLY file whose `vertex` element carries, per Gaussian, `x y z`, `f_dc_0..2`,
`f_rest_*` (0, 9, 24 or 45 of them, stored channel-major), `opacity` (a logit), `scale_0..2`
(natural-log scales) and `rot_0..3` (quaternion w, x, y, z). Anything else (normals, extra
attributes, other elements after `vertex`) is ignored. A file with a `chunk` element is the
SuperSplat compressed layout and goes to `compressed_ply`.

The header parser and element reader here are generic PLY: `compressed_ply` reuses them.
Every problem is a `SplatFileError` naming the file; sizes are checked against the file's length
before anything is allocated, so a corrupt header cannot ask for terabytes.
"""

from __future__ import annotations

import io
import itertools
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Iterable

import numpy as np

from ..gaussians import SH_COUNTS, Gaussians
from ..atomic import atomic_write
from .errors import SplatFileError

__all__ = ["load", "save", "read_header", "read_elements", "PlyHeader", "PlyElement", "PlyProperty",
           "PlyTable", "sh_from_file_layout", "check_finite"]

# PLY scalar type names (both spellings) -> numpy type code without byte order.
SCALAR_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}

MAX_HEADER_BYTES = 1 << 20  # real headers are a few KiB; this bounds the scan of a non-PLY file
_READ_BLOCK = 1 << 16
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
F_REST_COUNTS = {3 * (k - 1): k for k in SH_COUNTS}  # 0, 9, 24, 45 -> K


# --------------------------------------------------------------------------------------------
# Header


@dataclass(frozen=True)
class PlyProperty:
    name: str
    type_code: str  # numpy code without byte order, e.g. "f4"
    list_count_code: str | None = None  # set for `property list <count> <item> name`

    @property
    def is_list(self) -> bool:
        return self.list_count_code is not None


@dataclass(frozen=True)
class PlyElement:
    name: str
    count: int
    properties: tuple[PlyProperty, ...]

    @property
    def is_fixed_size(self) -> bool:
        return not any(p.is_list for p in self.properties)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.properties)

    def row_dtype(self, byte_order: str) -> np.dtype:
        """The packed structured dtype of one binary row (fixed-size elements only)."""
        return np.dtype([(p.name, byte_order + p.type_code) for p in self.properties])


@dataclass(frozen=True)
class PlyHeader:
    format: str  # "ascii", "binary_little_endian" or "binary_big_endian"
    elements: tuple[PlyElement, ...]
    header_length: int  # bytes up to and including the newline after `end_header`
    comments: tuple[str, ...] = ()

    @property
    def byte_order(self) -> str | None:
        return FORMATS[self.format]

    def element(self, name: str) -> PlyElement | None:
        return next((e for e in self.elements if e.name == name), None)


def read_header(path: str | os.PathLike) -> PlyHeader:
    """Parse the header of the PLY file at `path`."""
    path = Path(path)
    with _open(path) as f:
        return _parse_header(path, f)


def _open(path: Path) -> BinaryIO:
    try:
        return open(path, "rb")
    except OSError as e:
        raise SplatFileError(path, f"cannot read file: {e.strerror or e}") from None


def _header_bytes(path: Path, f: BinaryIO) -> tuple[bytes, int]:
    """The header text before `end_header`, and the header's length in bytes."""
    buf = f.read(_READ_BLOCK)
    if not (buf.startswith(b"ply\n") or buf.startswith(b"ply\r\n")):
        raise SplatFileError(path, "not a PLY file (it does not start with 'ply')")
    while True:
        at = buf.find(b"\nend_header")
        end = buf.find(b"\n", at + 1) if at >= 0 else -1
        if end >= 0:
            break
        if len(buf) > MAX_HEADER_BYTES:
            raise SplatFileError(path, f"malformed header: no end_header in the first {MAX_HEADER_BYTES} bytes")
        block = f.read(_READ_BLOCK)
        if not block:
            if at < 0:
                raise SplatFileError(path, "truncated header: the file ends before end_header")
            end = len(buf)  # `end_header` is the last line and no data follows
            break
        buf += block
    tail = buf[at + len(b"\nend_header"):end].strip()
    if tail:
        raise SplatFileError(path, f"malformed header: unexpected {tail[:20]!r} after end_header")
    return buf[:at], min(end + 1, len(buf))


def _parse_header(path: Path, f: BinaryIO) -> PlyHeader:
    text, length = _header_bytes(path, f)
    lines = text.decode("utf-8", errors="replace").splitlines()[1:]  # drop "ply"
    fmt: str | None = None
    comments: list[str] = []
    elements: list[tuple[str, int, list[PlyProperty]]] = []
    for number, line in enumerate(lines, start=2):
        words = line.split()
        if not words:
            continue
        keyword = words[0]
        if keyword in ("comment", "obj_info"):
            comments.append(line[len(keyword):].strip())
        elif keyword == "format":
            fmt = _parse_format(path, words, number)
        elif keyword == "element":
            elements.append(_parse_element(path, words, number, elements))
        elif keyword == "property":
            if not elements:
                raise SplatFileError(path, f"malformed header: property before any element (line {number})")
            _add_property(path, words, number, elements[-1])
        else:
            raise SplatFileError(path, f"malformed header: unknown keyword {keyword!r} (line {number})")
    if fmt is None:
        raise SplatFileError(path, "malformed header: no format line")
    frozen = tuple(PlyElement(name, count, tuple(props)) for name, count, props in elements)
    return PlyHeader(fmt, frozen, length, tuple(comments))


def _parse_format(path: Path, words: list[str], number: int) -> str:
    if len(words) < 2 or words[1] not in FORMATS:
        got = words[1] if len(words) > 1 else ""
        raise SplatFileError(path, f"unknown PLY format {got!r} (line {number}); "
                                   f"expected one of {', '.join(FORMATS)}")
    return words[1]


def _parse_element(path: Path, words: list[str], number: int,
                   elements: list[tuple[str, int, list[PlyProperty]]]) -> tuple[str, int, list[PlyProperty]]:
    if len(words) != 3 or not (words[2].isascii() and words[2].isdigit()):  # "²".isdigit() is True
        raise SplatFileError(path, f"malformed header: bad element line {' '.join(words)!r} (line {number})")
    if any(name == words[1] for name, _, _ in elements):
        raise SplatFileError(path, f"malformed header: duplicate element {words[1]!r}")
    return words[1], int(words[2]), []


def _add_property(path: Path, words: list[str], number: int,
                  element: tuple[str, int, list[PlyProperty]]) -> None:
    def scalar(type_name: str) -> str:
        if type_name not in SCALAR_TYPES:
            raise SplatFileError(path, f"malformed header: unknown property type {type_name!r} (line {number})")
        return SCALAR_TYPES[type_name]

    if len(words) == 5 and words[1] == "list":
        prop = PlyProperty(words[4], scalar(words[3]), scalar(words[2]))
    elif len(words) == 3:
        prop = PlyProperty(words[2], scalar(words[1]))
    else:
        raise SplatFileError(path, f"malformed header: bad property line {' '.join(words)!r} (line {number})")
    if any(p.name == prop.name for p in element[2]):
        raise SplatFileError(path, f"malformed header: duplicate property {prop.name!r} in element {element[0]!r}")
    element[2].append(prop)


# --------------------------------------------------------------------------------------------
# Element data


class PlyTable:
    """The rows of one element; `gather` pulls named columns out as one (N, k) array."""

    def __init__(self, path: Path, element: PlyElement, matrix: np.ndarray | None = None,
                 rows: np.ndarray | None = None) -> None:
        self.path = path
        self.element = element
        self._matrix = matrix  # (N, P) when all columns share one type (fast path) or ascii
        self._rows = rows  # structured array otherwise
        self._index = {name: i for i, name in enumerate(element.names)}

    def __len__(self) -> int:
        return self.element.count

    def missing(self, names: Iterable[str]) -> list[str]:
        return [n for n in names if n not in self._index]

    def gather(self, names: Iterable[str], dtype: np.dtype | type = np.float32,
               out: np.ndarray | None = None) -> np.ndarray:
        """Columns `names` as an (N, k) array of `dtype` (native byte order), written into `out`
        (any (N, k) view, e.g. a strided slice of the final array) when given."""
        names = list(names)
        missing = self.missing(names)
        if missing:
            raise SplatFileError(self.path, f"missing required property {missing[0]!r} in element "
                                            f"{self.element.name!r}")
        if out is None:
            out = np.empty((len(self), len(names)), dtype)
        with np.errstate(over="ignore", invalid="ignore"):  # doubles beyond float32 become inf: callers check
            if self._matrix is not None:
                # Copy runs of adjacent columns as blocks: far faster than a fancy-index gather.
                for j, i, width in _runs([self._index[n] for n in names]):
                    out[:, j:j + width] = self._matrix[:, i:i + width]
            else:
                for j, name in enumerate(names):
                    out[:, j] = self._rows[name]
        return out


def _runs(indices: list[int]) -> list[tuple[int, int, int]]:
    """Split column indices into (output start, source start, width) runs of consecutive columns."""
    runs: list[tuple[int, int, int]] = []
    for j, i in enumerate(indices):
        if runs and runs[-1][1] + runs[-1][2] == i:
            runs[-1] = (runs[-1][0], runs[-1][1], runs[-1][2] + 1)
        else:
            runs.append((j, i, 1))
    return runs


def read_elements(path: str | os.PathLike, header: PlyHeader, wanted: Iterable[str]) -> dict[str, PlyTable]:
    """Read the elements named in `wanted` (all must exist). Elements before the last wanted one
    are skipped and so must be fixed-size; elements after it are never looked at."""
    path = Path(path)
    wanted = set(wanted)
    for name in wanted:
        if header.element(name) is None:
            raise SplatFileError(path, f"missing element {name!r}")
    last = max(i for i, e in enumerate(header.elements) if e.name in wanted)
    span = header.elements[:last + 1]
    for element in span:
        if element.name in wanted and not element.is_fixed_size:
            raise SplatFileError(path, f"unsupported list property in element {element.name!r}")
        if not element.is_fixed_size:  # its rows have varying sizes: where later data starts is unknown
            target = header.elements[last].name
            raise SplatFileError(path, f"element {element.name!r} before {target!r} has a list property; "
                                       f"cannot locate the {target!r} data")
    with _open(path) as f:
        size = os.fstat(f.fileno()).st_size
        if header.format == "ascii":
            return _read_ascii(path, f, header, span, wanted, size)
        return _read_binary(path, f, header, span, wanted, size)


def _read_binary(path: Path, f: BinaryIO, header: PlyHeader, span: tuple[PlyElement, ...],
                 wanted: set[str], size: int) -> dict[str, PlyTable]:
    order = header.byte_order
    offsets, offset = [], header.header_length
    for element in span:
        offsets.append(offset)
        offset += element.count * element.row_dtype(order).itemsize
    if offset > size:  # checked before any allocation: a corrupt count fails here, fast
        bad = next(e for e, o in zip(span, offsets)
                   if o + e.count * e.row_dtype(order).itemsize > size)
        raise SplatFileError(path, f"truncated data: element {bad.name!r} declares {bad.count} rows, "
                                   f"the header needs {offset - header.header_length} data bytes but "
                                   f"the file holds {max(0, size - header.header_length)}")
    tables = {}
    for element, start in zip(span, offsets):
        if element.name in wanted:
            tables[element.name] = _read_binary_element(path, f, element, order, start)
    return tables


def _read_binary_element(path: Path, f: BinaryIO, element: PlyElement, order: str, start: int) -> PlyTable:
    dtype = element.row_dtype(order)
    raw = np.empty(element.count * dtype.itemsize, np.uint8)
    f.seek(start)
    if f.readinto(raw) != raw.size:  # the file shrank since we measured it
        raise SplatFileError(path, f"truncated data in element {element.name!r}")
    codes = {p.type_code for p in element.properties}
    if len(codes) == 1 and element.properties:  # uniform rows: view as a plain (N, P) matrix
        matrix = raw.view(order + codes.pop()).reshape(element.count, len(element.properties))
        return PlyTable(path, element, matrix=matrix)
    return PlyTable(path, element, rows=raw.view(dtype))


def _read_ascii(path: Path, f: BinaryIO, header: PlyHeader, span: tuple[PlyElement, ...],
                wanted: set[str], size: int) -> dict[str, PlyTable]:
    # Every value takes at least one character and one separator: a cheap bound on the count.
    least = sum(e.count * 2 * len(e.properties) for e in span) - 1
    if least > size - header.header_length:
        raise SplatFileError(path, f"truncated data: the header declares more rows than the "
                                   f"{size - header.header_length} data bytes can hold")
    f.seek(header.header_length)
    text = io.TextIOWrapper(f, encoding="ascii", errors="replace")
    lines = (line for line in text if line.strip())
    tables = {}
    for element in span:
        rows = list(itertools.islice(lines, element.count))
        if len(rows) < element.count:
            raise SplatFileError(path, f"truncated data: element {element.name!r} declares "
                                       f"{element.count} rows, the file has {len(rows)}")
        if element.name in wanted:
            tables[element.name] = PlyTable(path, element, matrix=_parse_ascii_rows(path, element, rows))
    text.detach()
    return tables


def _parse_ascii_rows(path: Path, element: PlyElement, rows: list[str]) -> np.ndarray:
    width = len(element.properties)
    if not rows:
        return np.zeros((0, width))
    try:
        matrix = np.loadtxt(rows, dtype=np.float64, comments=None, ndmin=2)
    except ValueError:
        raise SplatFileError(path, f"malformed ascii data in element {element.name!r}: expected rows "
                                   f"of {width} numbers") from None
    if matrix.shape[1] != width:
        raise SplatFileError(path, f"malformed ascii data in element {element.name!r}: rows have "
                                   f"{matrix.shape[1]} values, the header declares {width}")
    return matrix


# --------------------------------------------------------------------------------------------
# Conversion to and from the in-memory layout


def check_finite(path: Path, values: np.ndarray, names: list[str] | tuple[str, ...]) -> None:
    """Raise naming the first column of `values` (N, k) that holds NaN or Inf."""
    finite = np.isfinite(values)
    if not finite.all():
        column = int(np.argmin(finite.all(axis=0)))
        raise SplatFileError(path, f"non-finite values in property {names[column]!r}")


def f_rest_names(count: int) -> list[str]:
    return [f"f_rest_{i}" for i in range(count)]


def sh_from_file_layout(dc: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """(N,3) DC and (N, 3*(K-1)) channel-major f_rest -> (N, K, 3) coefficient-major."""
    n, k = len(dc), rest.shape[1] // 3 + 1
    sh = np.empty((n, k, 3), np.float32)
    sh[:, 0, :] = dc
    sh[:, 1:, :] = rest.reshape(n, 3, k - 1).transpose(0, 2, 1)
    return sh


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
    table = read_elements(path, header, ["vertex"])["vertex"]
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
    bad = gaussians.non_finite()
    if bad is not None:  # such a file would not load again
        raise SplatFileError(path, f"cannot save non-finite values in {bad}")
    try:
        with atomic_write(path) as f:
            f.write(_header_text(len(gaussians), gaussians.degree))
            _write_body(f, gaussians)
    except OSError as e:
        raise SplatFileError(path, f"cannot write file: {e.strerror or e}") from None
