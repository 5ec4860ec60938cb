"""PLY files in general (not only splats): the header parser and the element reader, with numpy.

`read_header(path)` parses the header; `read_elements(path, header, names)` reads whole
elements as `PlyTable`s, whose `gather` pulls named columns out. Every problem is a
`SplatFileError` naming the file; sizes are checked against the file's length before anything
is allocated, so a corrupt header cannot ask for terabytes. The 3DGS layouts on top of it are
`ply` (standard) and `compressed_ply` (SuperSplat).
"""

from __future__ import annotations

import io
import itertools
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO, Callable, Iterable

import numpy as np

from .errors import SplatFileError, os_errors

__all__ = ["read_header", "read_elements", "PlyHeader", "PlyElement", "PlyProperty", "PlyTable",
           "check_finite", "SCALAR_TYPES", "FORMATS", "MAX_HEADER_BYTES"]

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
    with os_errors(path, "cannot read file"):
        return open(path, "rb")


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
    elements: list[_Draft] = []
    element_names: set[str] = set()  # sets, not scans: a hostile header has 10^5 names
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
            elements.append(_parse_element(path, words, number, element_names))
        elif keyword == "property":
            if not elements:
                raise SplatFileError(path, f"malformed header: property before any element (line {number})")
            _add_property(path, words, number, elements[-1])
        else:
            raise SplatFileError(path, f"malformed header: unknown keyword {keyword!r} (line {number})")
    if fmt is None:
        raise SplatFileError(path, "malformed header: no format line")
    frozen = tuple(PlyElement(e.name, e.count, tuple(e.properties)) for e in elements)
    return PlyHeader(fmt, frozen, length, tuple(comments))


def _parse_format(path: Path, words: list[str], number: int) -> str:
    if len(words) < 2 or words[1] not in FORMATS:
        got = words[1] if len(words) > 1 else ""
        raise SplatFileError(path, f"unknown PLY format {got!r} (line {number}); "
                                   f"expected one of {', '.join(FORMATS)}")
    return words[1]


@dataclass
class _Draft:
    """An element while its header lines are read."""
    name: str
    count: int
    properties: list[PlyProperty] = field(default_factory=list)
    names: set[str] = field(default_factory=set)


def _parse_element(path: Path, words: list[str], number: int, seen: set[str]) -> _Draft:
    if len(words) != 3 or not (words[2].isascii() and words[2].isdigit()):  # "²".isdigit() is True
        raise SplatFileError(path, f"malformed header: bad element line {' '.join(words)!r} (line {number})")
    if words[1] in seen:
        raise SplatFileError(path, f"malformed header: duplicate element {words[1]!r}")
    seen.add(words[1])
    return _Draft(words[1], int(words[2]))


def _add_property(path: Path, words: list[str], number: int, element: _Draft) -> None:
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
    if prop.name in element.names:
        raise SplatFileError(path, f"malformed header: duplicate property {prop.name!r} in element {element.name!r}")
    element.names.add(prop.name)
    element.properties.append(prop)


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


def read_elements(path: str | os.PathLike, header: PlyHeader, wanted: Iterable[str],
                  check_rows: Callable[[Path, int], None] | None = None) -> dict[str, PlyTable]:
    """Read the elements named in `wanted` (all must exist). Elements before the last wanted one
    are skipped and so must be fixed-size; elements after it are never looked at.
    `check_rows(path, total rows wanted)` runs once the counts are known to fit the file and
    before anything is allocated (the caller's memory bound)."""
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
    check = (lambda: check_rows(path, sum(e.count for e in span if e.name in wanted))) \
        if check_rows is not None else (lambda: None)
    with _open(path) as f:
        size = os.fstat(f.fileno()).st_size
        if header.format == "ascii":
            return _read_ascii(path, f, header, span, wanted, size, check)
        return _read_binary(path, f, header, span, wanted, size, check)


def _read_binary(path: Path, f: BinaryIO, header: PlyHeader, span: tuple[PlyElement, ...],
                 wanted: set[str], size: int, check: Callable[[], None]) -> dict[str, PlyTable]:
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
    check()
    tables = {}
    for element, start in zip(span, offsets):
        if element.name in wanted:
            tables[element.name] = _read_binary_element(path, f, element, order, start)
    return tables


def _read_binary_element(path: Path, f: BinaryIO, element: PlyElement, order: str, start: int) -> PlyTable:
    if not element.properties:  # rows of zero bytes: nothing to read (numpy cannot view them)
        return PlyTable(path, element, matrix=np.zeros((element.count, 0), np.float32))
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
                wanted: set[str], size: int, check: Callable[[], None]) -> dict[str, PlyTable]:
    # Every value takes at least one character and one separator: a cheap bound on the count.
    least = sum(e.count * 2 * len(e.properties) for e in span) - 1
    if least > size - header.header_length:
        raise SplatFileError(path, f"truncated data: the header declares more rows than the "
                                   f"{size - header.header_length} data bytes can hold")
    check()
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


def check_finite(path: Path, values: np.ndarray, names: list[str] | tuple[str, ...]) -> None:
    """Raise naming the first column of `values` (N, k) that holds NaN or Inf."""
    finite = np.isfinite(values)
    if not finite.all():
        column = int(np.argmin(finite.all(axis=0)))
        raise SplatFileError(path, f"non-finite values in property {names[column]!r}")

