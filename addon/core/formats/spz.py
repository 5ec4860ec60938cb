"""Niantic SPZ: read versions 2, 3 and 4; write version 4 (or 2/3 on request).

Verified against nianticlabs/spz (`src/cc/load-spz.cc`, `load-spz.h`, `splat-types.h`,
`extensions/README.md`, `extensions/cc/coordinate-system-adobe.cc`) at LATEST_SPZ_HEADER_VERSION 4.

Containers
    v2, v3   the whole file is one gzip stream of a 16-byte header
             `<u32 magic 0x5053474e "NGSP", u32 version, u32 numPoints, u8 shDegree,
             u8 fractionalBits, u8 flags, u8 reserved>` then the attribute arrays back to back;
             extension records (flags & 2), if any, follow the arrays.
    v4       a plaintext 32-byte header `<magic, version, numPoints, shDegree, fractionalBits, flags,
             u8 numStreams, u32 tocByteOffset, 12 reserved bytes>`, extension records in
             [32, tocByteOffset), a table of contents of numStreams x `<u64 compressed,
             u64 uncompressed>`, then one independent zstd frame per non-empty attribute array.
             zstd is not in Python's standard library (before 3.14): reading or writing v4 needs
             the `zstandard` package; without it a clear SplatFileError says so.
    Extension records are `<u32 type, u32 byteLength, payload>`; unknown types are skipped. The one
    that changes decoding, SPZ_ADOBE_coordinate_system (0xADBE0003, payload u32 frame id), is
    honoured for the axis-flip frames (ids 1..8) and refused for the rotated ones (9..16).

Attribute arrays, in file order (N = numPoints, D = 3, 8, 15, 24 for SH degree 1..4):
    positions  N x 3 x 24-bit two's-complement fixed point, value * 2^fractionalBits
    alphas     N  uint8 round(sigmoid(logit) * 255)
    colors     N x 3 uint8 round(f_dc * 0.15 * 255 + 127.5)   (0.15, not SH_C0: headroom for SH)
    scales     N x 3 uint8 round((log_scale + 10) * 16)
    rotations  v2: N x 3 uint8 round(xyz * 127.5 + 127.5) of the unit quaternion with w >= 0;
               v3+: N x uint32 "smallest three": bits 30-31 the index (x,y,z,w order) of the
               component left out (the largest |component|, made positive, derived on reading);
               the other three in index order from bit 20 down, each a sign bit and a 9-bit
               magnitude round(|c| / sqrt(1/2) * 511)
    sh         N x D x 3 uint8 round(c * 128) + 128, coefficient-major with RGB inner (the
               same order as Gaussians.sh[:, 1:]); degree-1 coefficients kept to 5 bits and higher
               ones to 4 bits by default (Niantic's defaults: bucket 8 and 16 of the 256 codes)

Coordinate frame: SPZ stores Niantic's RUB (x right, y up, z back, OpenGL); the 3DGS .ply is RDF
(x right, y down, z forward, OpenCV/COLMAP), per the Niantic README and its PLY converter. Loading
converts to RDF, so an .spz and the .ply it came from load identically; saving converts back:
y and z of positions negate, the quaternion's y and z negate (a 180 degree turn about x), and SH
coefficients odd in y or z (but not both) negate. SH degree 4 (SPZ only) is dropped to degree 3.

Quantisation (write then read; bounds hold for values inside each range):
    position    within 2^-(fractionalBits+1) (half a step); fractionalBits = 12 (about 0.24 mm in
                metre scenes) unless the scene needs fewer bits to fit 24 bits: |x| < 2^(23-fb)
    log_scale   within 1/32, range [-10, 5.9375]
    f_dc        within 0.5 / (0.15 * 255) = 0.0131, so the DC colour within 0.94/255; range
                |f_dc| <= 3.33 (colours -0.44..1.44)
    opacity     within 0.5/255 (alpha byte 0 and 255 decode to 0.25/255 and 1 - 0.25/255)
    rotation    v3+: the three stored components within sqrt(1/2)/511/2 = 6.9e-4, the derived
                (largest) one within 2.1e-3; v2: x, y, z within 1/255 and w derived from them,
                which is inaccurate when |w| is small (the reason v3 replaced it)
    sh (rest)   within half a bucket: 1/32 for degree 1 (5 bits), 1/16 for degrees 2-3 (4 bits),
                1/256 with 8 bits; range [-1, 1 - bucket/128] (0.9375 and 0.875 by default)
Re-saving what was loaded reproduces the quantised data exactly (bit-exact from the second save
on; from the first for files whose codes are canonical, as Niantic's are).
"""

from __future__ import annotations

import gzip
import os
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType

import numpy as np

from ..gaussians import Gaussians
from ..atomic import atomic_write
from ..formats_common.errors import SplatFileError, check_savable, os_errors
from ..formats_common.limits import check_expansion, check_gaussian_count
from .splat import decode_alpha, encode_alpha

__all__ = ["load", "load_with_flag", "memory_needed", "save", "Packed", "read_packed", "unpack", "pack", "serialize",
           "LATEST_VERSION", "READ_VERSIONS"]

MAGIC = 0x5053474E  # b"NGSP" little-endian
LATEST_VERSION = 4
READ_VERSIONS = (2, 3, 4)
COLOR_SCALE = 0.15
FRACTIONAL_BITS = 12  # Niantic's choice; lowered on write only when the scene does not fit 24 bits
MAX_FRACTIONAL_BITS = 24  # what Niantic's reader accepts
DEFAULT_SH1_BITS = 5
DEFAULT_SH_REST_BITS = 4
ZSTD_LEVEL = 12  # Niantic's level
FLAG_ANTIALIASED = 0x1
FLAG_EXTENSIONS = 0x2
EXT_COORDINATE_SYSTEM = 0xADBE0003
COORD_RUB = 4
# Niantic rejects numPoints > fileSize * 1024 / 9 before decompressing (a generous zstd ratio
# bound); deflate cannot exceed 1032:1. Both let a lying header fail before any allocation.
_ZSTD_MAX_RATIO = 1024
_DEFLATE_MAX_RATIO = 1032
_CHUNK = 1 << 24  # decompression works in bounded chunks: allocation follows the real data

_LEGACY_HEADER = struct.Struct("<IIIBBBB")  # 16 bytes
_NGSP_HEADER = struct.Struct("<IIIBBBBI12s")  # 32 bytes
_SH_DIMS = {0: 0, 1: 3, 2: 8, 3: 15, 4: 24}
_STREAMS = ("positions", "alphas", "colors", "scales", "rotations", "sh")
_SQRT1_2 = np.sqrt(0.5)
# For each largest-component index (x,y,z,w order), the other three in stored (ascending) order.
_OTHERS = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])


@dataclass(eq=False)
class Packed:
    """An SPZ file's content in its quantised domain (the file's own frame, before conversion)."""

    version: int
    sh_degree: int
    fractional_bits: int
    antialiased: bool
    coordinate_system: int  # Niantic CoordinateSystem id the data is stored in (4 = RUB)
    positions: np.ndarray  # (N, 3) int32 fixed point
    alphas: np.ndarray  # (N,) uint8
    colors: np.ndarray  # (N, 3) uint8
    scales: np.ndarray  # (N, 3) uint8
    rotations: np.ndarray  # (N, 3) uint8 for v2, (N,) uint32 smallest-three for v3+
    sh: np.ndarray  # (N, D, 3) uint8

    def __len__(self) -> int:
        return len(self.positions)

    def arrays(self) -> dict[str, np.ndarray]:
        return {name: getattr(self, name) for name in _STREAMS}


# ----------------------------------------------------------------------------- codecs

def _zstd(path: Path, action: str) -> ModuleType:
    try:
        import zstandard
    except ImportError:
        raise SplatFileError(path, f"cannot {action} SPZ version 4: it is zstd-compressed and the "
                                   f"'zstandard' package is not installed (pip install zstandard; "
                                   f"or save with version=3, which uses gzip)") from None
    return zstandard


def _unzstd(frame: bytes, size: int, path: Path, what: str) -> bytes:
    zstandard = _zstd(path, "read")
    out = bytearray()
    try:
        reader = zstandard.ZstdDecompressor().stream_reader(frame)
        while len(out) < size:
            chunk = reader.read(min(size - len(out), _CHUNK))
            if not chunk:
                break
            out += chunk
        extra = reader.read(1)
    except zstandard.ZstdError as error:
        raise SplatFileError(path, f"corrupt zstd stream for {what}: {error}") from None
    if len(out) != size or extra:
        got = f"{len(out)}" if not extra else f"more than {size}"
        raise SplatFileError(path, f"{what} stream decompresses to {got} bytes; the header needs {size}")
    return bytes(out)


class _Gunzip:
    """Bounded incremental gunzip: never produces more than asked, so a lying header cannot make
    it allocate more than the compressed data really holds."""

    def __init__(self, data: bytes, path: Path) -> None:
        self._d = zlib.decompressobj(16 + zlib.MAX_WBITS)
        self._tail = data
        self._path = path
        # ISIZE, the trailer's uncompressed size mod 2^32 (of a single-member stream, which is
        # all SPZ writes and all this reader accepts)
        self.declared_size = struct.unpack_from("<I", data, len(data) - 4)[0] if len(data) >= 18 else None

    def read(self, size: int) -> bytearray:
        out = bytearray()
        try:
            while len(out) < size and not self._d.eof:
                chunk = self._d.decompress(self._tail, min(size - len(out), _CHUNK))
                self._tail = self._d.unconsumed_tail
                if not chunk and not self._tail:
                    break  # input exhausted
                out += chunk
        except zlib.error as error:
            raise SplatFileError(self._path, f"corrupt gzip stream: {error}") from None
        return out  # not copied to bytes: the arrays are views of it

    @property
    def eof(self) -> bool:
        return self._d.eof


# ----------------------------------------------------------------------------- frames

def _frame_signs(coordinate_system: int, path: Path) -> np.ndarray:
    """Per-axis signs taking coordinates stored in `coordinate_system` to RDF (3DGS .ply)."""
    cs = COORD_RUB if coordinate_system == 0 else coordinate_system  # unspecified means RUB
    if not 1 <= cs <= 8:
        raise SplatFileError(path, f"data stored in coordinate system {coordinate_system}; only the "
                                   f"axis-flip frames 1..8 are supported (not the rotated 9..16)")
    bits = cs - 1  # Niantic's enum: bit 0 set = Right, bit 1 set = Up, bit 2 set = Front
    return np.array([1.0 if bits & 1 else -1.0, -1.0 if bits & 2 else 1.0, 1.0 if bits & 4 else -1.0])


def _sh_signs(s: np.ndarray) -> np.ndarray:
    """Sign of each SH coefficient (degree 1..3, 15 of them) under the axis flips `s`: the parity
    of each real SH basis function in x, y, z (same table as Niantic's flipSh)."""
    x, y, z = s
    return np.array([y, z, x,
                     x * y, y * z, 1, x * z, 1,
                     y, x * y * z, y, z, x, z, x], dtype=np.float32)


def _quat_signs(s: np.ndarray) -> np.ndarray:
    """Multipliers for w, x, y, z under axis flips `s` (the rotation F R F)."""
    x, y, z = s
    return np.array([1.0, y * z, x * z, x * y])


# ----------------------------------------------------------------------------- reading

def _stream_sizes(n: int, version: int, sh_degree: int) -> list[int]:
    rotation_bytes = 4 if version >= 3 else 3
    return [9 * n, n, 3 * n, 3 * n, rotation_bytes * n, 3 * _SH_DIMS[sh_degree] * n]


def _check_header(path: Path, version: int, n: int, sh_degree: int, fractional_bits: int) -> None:
    if version not in READ_VERSIONS:
        raise SplatFileError(path, f"unsupported SPZ version {version} (this reader knows "
                                   f"{', '.join(map(str, READ_VERSIONS))})")
    if sh_degree not in _SH_DIMS:
        raise SplatFileError(path, f"unsupported SH degree {sh_degree} (SPZ allows 0..4)")
    if fractional_bits > MAX_FRACTIONAL_BITS:
        raise SplatFileError(path, f"fractionalBits {fractional_bits} is above {MAX_FRACTIONAL_BITS}")


def _parse_extensions(block: bytes, path: Path) -> int:
    """Walk extension records; return the stored coordinate system (RUB when none says)."""
    coordinate_system = COORD_RUB
    offset = 0
    while offset < len(block):
        if len(block) - offset < 8:
            raise SplatFileError(path, "truncated extension record")
        kind, length = struct.unpack_from("<II", block, offset)
        offset += 8
        if length > len(block) - offset:
            raise SplatFileError(path, f"extension 0x{kind:08x} claims {length} bytes past its block")
        if kind == EXT_COORDINATE_SYSTEM:
            if length < 4:
                raise SplatFileError(path, "coordinate-system extension too short")
            coordinate_system = struct.unpack_from("<I", block, offset)[0]
        offset += length
    return coordinate_system


def _packed_from_streams(path: Path, version: int, n: int, sh_degree: int, fractional_bits: int,
                         flags: int, coordinate_system: int, streams: list) -> Packed:
    """The arrays as views of `streams` (bytes-like; not copied, so a load holds the decompressed
    data once)."""
    positions, alphas, colors, scales, rotations, sh = streams
    b = np.frombuffer(positions, np.uint8).reshape(n, 3, 3).astype(np.int32)
    fixed = b[..., 0] | (b[..., 1] << 8) | (b[..., 2] << 16)
    fixed = (fixed ^ 0x800000) - 0x800000  # sign-extend 24 -> 32 bits
    if version >= 3:
        rot = np.frombuffer(rotations, "<u4").astype(np.uint32)
    else:
        rot = np.frombuffer(rotations, np.uint8).reshape(n, 3)
    return Packed(version=version, sh_degree=sh_degree, fractional_bits=fractional_bits,
                  antialiased=bool(flags & FLAG_ANTIALIASED), coordinate_system=coordinate_system,
                  positions=fixed, alphas=np.frombuffer(alphas, np.uint8),
                  colors=np.frombuffer(colors, np.uint8).reshape(n, 3),
                  scales=np.frombuffer(scales, np.uint8).reshape(n, 3), rotations=rot,
                  sh=np.frombuffer(sh, np.uint8).reshape(n, _SH_DIMS[sh_degree], 3))


def _read_legacy(stream: _Gunzip | bytes, compressed_size: int, path: Path) -> Packed:
    """A v2/v3 stream: gzip (or, leniently, already plain) header + arrays (+ extensions)."""
    plain = isinstance(stream, bytes)
    head = stream[:16] if plain else stream.read(16)
    if len(head) < 16:
        raise SplatFileError(path, f"truncated: {len(head)} of the 16 header bytes")
    magic, version, n, sh_degree, fractional_bits, flags, _ = _LEGACY_HEADER.unpack(head)
    if magic != MAGIC:
        raise SplatFileError(path, f"wrong magic 0x{magic:08x} inside the gzip stream (expected NGSP)")
    _check_header(path, version, n, sh_degree, fractional_bits)
    sizes = _stream_sizes(n, version, sh_degree)
    total = sum(sizes)
    if not plain and total > compressed_size * _DEFLATE_MAX_RATIO + 1024:
        raise SplatFileError(path, f"header claims {n} points ({total} bytes), more than a "
                                   f"{compressed_size}-byte gzip stream can hold")
    if not plain and stream.declared_size is not None and 16 + total < 1 << 32 \
            and stream.declared_size < 16 + total:
        # The gzip trailer records what the stream decompresses to (mod 2^32): a header claiming
        # more is refused before anything is decompressed.
        raise SplatFileError(path, f"truncated: the header claims {n} points ({16 + total} bytes "
                                   f"with the header), the gzip stream holds {stream.declared_size}")
    check_gaussian_count(path, n, "points")  # before decompressing: the ratio bounds too little
    # Only the 16 header bytes are inflated yet: deflate's 1032:1 and the count let a 185 KB
    # gzip stream of zeros declare 10M points (1.95 GB, issue 33); the expansion bound does not.
    check_expansion(path, n, sh_degree, compressed_size)
    payload = memoryview(stream)[16:16 + total] if plain else memoryview(stream.read(total))
    if len(payload) < total:
        raise SplatFileError(path, f"truncated: {len(payload)} of {total} data bytes for {n} points")
    coordinate_system = COORD_RUB
    if flags & FLAG_EXTENSIONS:
        # The current Niantic library writes legacy extensions after the arrays.
        trailing = stream[16 + total:] if plain else stream.read(1 << 20)
        coordinate_system = _parse_extensions(trailing, path)
    if not plain:
        stream.read(1 << 20)  # reach the gzip trailer so zlib checks the CRC
        if not stream.eof:
            raise SplatFileError(path, "gzip stream is truncated or holds unexpected trailing data")
    offsets = np.cumsum([0] + sizes)
    streams = [payload[offsets[i]:offsets[i + 1]] for i in range(len(sizes))]
    return _packed_from_streams(path, version, n, sh_degree, fractional_bits, flags,
                                coordinate_system, streams)


def _read_ngsp(data: bytes, path: Path) -> Packed:
    if len(data) < 16:
        raise SplatFileError(path, f"truncated: {len(data)} bytes, shorter than any SPZ header")
    version = struct.unpack_from("<I", data, 4)[0]
    if version in (2, 3):
        return _read_legacy(data, len(data), path)  # an uncompressed legacy stream
    if len(data) < _NGSP_HEADER.size:
        raise SplatFileError(path, f"truncated: {len(data)} of the 32 header bytes")
    _, version, n, sh_degree, fractional_bits, flags, num_streams, toc_offset, _ = \
        _NGSP_HEADER.unpack_from(data)
    _check_header(path, version, n, sh_degree, fractional_bits)
    if n > len(data) * _ZSTD_MAX_RATIO // 9:
        raise SplatFileError(path, f"header claims {n} points, more than a {len(data)}-byte file can hold")
    check_gaussian_count(path, n, "points")  # before decompressing: the ratio bounds too little
    check_expansion(path, n, sh_degree, len(data))
    sizes = _stream_sizes(n, version, sh_degree)
    names = [name for name, size in zip(_STREAMS, sizes) if size]
    if num_streams != len(names):
        raise SplatFileError(path, f"{num_streams} streams in the table of contents; {n} points of SH "
                                   f"degree {sh_degree} need {len(names)}")
    toc_end = toc_offset + 16 * num_streams
    if toc_offset < _NGSP_HEADER.size or toc_end > len(data):
        raise SplatFileError(path, f"truncated: table of contents at {toc_offset}..{toc_end} lies "
                                   f"outside the {len(data)}-byte file")
    coordinate_system = COORD_RUB
    if flags & FLAG_EXTENSIONS:
        coordinate_system = _parse_extensions(data[_NGSP_HEADER.size:toc_offset], path)
    toc = np.frombuffer(data, "<u8", count=2 * num_streams, offset=toc_offset).reshape(-1, 2)
    need = [size for size in sizes if size]
    for name, (_, uncompressed), size in zip(names, toc, need):
        if int(uncompressed) != size:
            raise SplatFileError(path, f"{name} stream holds {int(uncompressed)} bytes; {n} points "
                                       f"need {size}")
    compressed = [int(c) for c in toc[:, 0]]
    if sum(compressed) != len(data) - toc_end:
        problem = "truncated" if sum(compressed) > len(data) - toc_end else "unexpected trailing data"
        raise SplatFileError(path, f"{problem}: streams total {sum(compressed)} bytes, the file has "
                                   f"{len(data) - toc_end} after the table of contents")
    offsets = toc_end + np.cumsum([0] + compressed)
    found = {name: _unzstd(data[offsets[i]:offsets[i + 1]], need[i], path, name)
             for i, name in enumerate(names)}
    streams = [found.get(name, b"") for name in _STREAMS]
    return _packed_from_streams(path, version, n, sh_degree, fractional_bits, flags,
                                coordinate_system, streams)


def read_packed(path: str | os.PathLike) -> Packed:
    """Read an SPZ file into its quantised domain (no conversion)."""
    path = Path(path)
    with os_errors(path, "cannot read file"):
        data = path.read_bytes()
    if data[:2] == b"\x1f\x8b":
        return _read_legacy(_Gunzip(data, path), len(data), path)
    if data[:4] == b"NGSP":
        return _read_ngsp(data, path)
    raise SplatFileError(path, f"not an SPZ file: starts with {data[:4]!r}, expected gzip or 'NGSP'")


def _decode_smallest_three(comp: np.ndarray) -> np.ndarray:
    """uint32 smallest-three codes -> (N, 4) float64 x, y, z, w."""
    comp = comp.astype(np.uint32)
    q = np.zeros((len(comp), 4))
    largest = (comp >> 30).astype(np.intp)
    rows = np.arange(len(comp))
    for j, shift in enumerate((20, 10, 0)):
        field = (comp >> shift) & 0x3FF
        value = _SQRT1_2 * (field & 0x1FF) / 511.0
        q[rows, _OTHERS[largest, j]] = np.where(field & 0x200, -value, value)
    q[rows, largest] = np.sqrt(np.maximum(0.0, 1.0 - np.sum(q * q, axis=1)))
    return q


def _unpack_rotations(packed: Packed) -> np.ndarray:
    """Quantised rotations -> (N, 4) float64 x, y, z, w (the file's component order)."""
    if packed.version >= 3:
        return _decode_smallest_three(packed.rotations)
    q = np.zeros((len(packed), 4))
    q[:, :3] = packed.rotations / 127.5 - 1.0
    q[:, 3] = np.sqrt(np.maximum(0.0, 1.0 - np.sum(q[:, :3] ** 2, axis=1)))
    return q


def unpack(packed: Packed, path: str | os.PathLike = "<memory>") -> Gaussians:
    """Dequantise and convert to the 3DGS .ply frame (RDF)."""
    path = Path(path)
    n = len(packed)
    s = _frame_signs(packed.coordinate_system, path)
    means = packed.positions * (s * 2.0 ** -packed.fractional_bits)
    log_scales = packed.scales / 16.0 - 10.0
    xyzw = _unpack_rotations(packed)
    quats = xyzw[:, [3, 0, 1, 2]] * _quat_signs(s)
    degree = min(packed.sh_degree, 3)  # Gaussians hold SH up to degree 3
    k = (degree + 1) ** 2
    sh = np.empty((n, k, 3), np.float32)
    sh[:, 0, :] = (packed.colors / 255.0 - 0.5) / COLOR_SCALE
    rest = sh[:, 1:, :]  # filled in place: no (N, K, 3) temporaries
    rest[...] = packed.sh[:, :k - 1, :]
    rest -= 128.0
    rest *= (_sh_signs(s)[:k - 1, None] / 128.0).astype(np.float32)
    return Gaussians(means, log_scales, quats, decode_alpha(packed.alphas), sh)


def memory_needed(n: int, sh_degree: int) -> int:
    """About how many bytes loading `n` points of SH degree `sh_degree` peaks at: the
    decompressed streams, the float32 result and the float64 working arrays (measured: a
    6M-point degree-3 file peaks at about this, see test_spz_hardening)."""
    streams = sum(_stream_sizes(n, 3, sh_degree))
    result = 4 * n * (3 + 3 + 4 + 1 + 3 * (min(sh_degree, 3) + 1) ** 2)
    return streams + result + 8 * n * 24


def load_with_flag(path: str | os.PathLike) -> tuple[Gaussians, bool]:
    """(Gaussians in the 3DGS .ply frame, the antialiased flag) of an SPZ file. Running out of
    memory is a SplatFileError saying how much the file needs."""
    packed = read_packed(path)
    try:
        return unpack(packed, path), bool(packed.antialiased)
    except MemoryError:
        n, degree = len(packed), packed.sh_degree
        del packed  # let go of it before formatting the message
        raise SplatFileError(path, f"not enough memory: loading {n} points of SH degree {degree} "
                                   f"needs about {memory_needed(n, degree) / 2**30:.1f} GiB") from None


def load(path: str | os.PathLike) -> Gaussians:
    """Read an SPZ file (v2, v3 or v4) into the 3DGS .ply frame."""
    return load_with_flag(path)[0]


# ----------------------------------------------------------------------------- writing

def _choose_fractional_bits(means: np.ndarray, path: Path) -> int:
    extent = float(np.abs(means).max(initial=0.0))
    for bits in range(FRACTIONAL_BITS, -1, -1):
        if np.rint(extent * 2.0 ** bits) <= (1 << 23) - 1:
            return bits
    raise SplatFileError(path, f"cannot write: a coordinate of magnitude {extent:g} does not fit "
                               f"SPZ's 24-bit fixed point (|x| < 8388607.5)")


def _encode_smallest_three(q: np.ndarray, largest: np.ndarray) -> np.ndarray:
    """Unit (N, 4) x, y, z, w -> uint32 codes storing all but component `largest` (per row)."""
    rows = np.arange(len(q))
    q = np.where(q[rows, largest][:, None] < 0, -q, q)  # -q is the same rotation; stored one >= 0
    comp = largest.astype(np.uint32) << 30
    for j, shift in enumerate((20, 10, 0)):
        value = q[rows, _OTHERS[largest, j]]
        magnitude = np.minimum(np.floor(511.0 * np.abs(value) / _SQRT1_2 + 0.5), 511).astype(np.uint32)
        comp |= ((np.signbit(value).astype(np.uint32) << 9) | magnitude) << shift
    return comp


def _choose_smallest_three(q: np.ndarray) -> np.ndarray:
    """Unit (N, 4) x, y, z, w -> smallest-three codes.

    Niantic leaves out the largest |component|. After quantising the others, the derived one can
    come out a hair smaller than another (near ties), and re-saving by that rule alone would flip
    codes. So when Niantic's choice does not represent q exactly but another code does (its three
    stored components on the 9-bit lattice), that code is kept. The left-out component must be
    >= 0.49 so that deriving it stays well conditioned.
    """
    rows = np.arange(len(q))
    # Lattice tolerance: float32 storage moves a component by < 5e-5 steps, while a derived component
    # that is not exact lies >= 1/1023 steps off the lattice (sqrt of a non-square integer <= 511^2).
    steps = np.abs(q) * (511.0 / _SQRT1_2)
    on_lattice = (np.abs(steps - np.rint(steps)) < 2e-4) & (steps < 511.5)
    exact = ((on_lattice.sum(axis=1, keepdims=True) - on_lattice) == 3) & (np.abs(q) >= 0.49)
    # Magnitudes compared at 1e-3 steps, so that components equal on the lattice tie exactly
    # whatever float noise they carry (then the first wins, like Niantic's strict '>' loop).
    magnitude = np.rint(steps * 1000.0)
    niantic = np.argmax(magnitude, axis=1)
    other = np.argmax(np.where(exact, magnitude, -1.0), axis=1)
    keep = exact[rows, niantic] | ~exact.any(axis=1)
    return _encode_smallest_three(q, np.where(keep, niantic, other))


def _pack_rotations(q: np.ndarray, version: int) -> np.ndarray:
    """(N, 4) x, y, z, w -> quantised rotations (see module docstring)."""
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    q = np.where(norm > 0, q / np.where(norm > 0, norm, 1.0), np.array([0.0, 0.0, 0.0, 1.0]))
    if version < 3:
        q = np.where(q[:, 3:] < 0, -q, q)
        return np.clip(np.rint(q[:, :3] * 127.5 + 127.5), 0, 255).astype(np.uint8)
    # Choosing again for the decoded value gives the same value in the code that a later save of
    # it would choose (they differ only where two codes hold exactly the same quaternion), so
    # saving what was loaded reproduces the bytes.
    return _choose_smallest_three(_decode_smallest_three(_choose_smallest_three(q)))


def _quantise_sh(values: np.ndarray, bits: int) -> np.ndarray:
    """round(c * 128) + 128 kept to `bits` bits: the nearest code on the lattice 128 + k * bucket
    (one rounding, so the error is at most half a bucket), clipped to the codes that fit a byte."""
    bucket = 1 << (8 - bits)
    steps = np.rint(values.astype(np.float64) * (128.0 / bucket))
    steps = np.clip(steps, -(128 // bucket), 127 // bucket)
    return (128 + steps * bucket).astype(np.uint8)


def pack(gaussians: Gaussians, version: int = LATEST_VERSION, *, antialiased: bool = False,
         sh1_bits: int = DEFAULT_SH1_BITS, sh_rest_bits: int = DEFAULT_SH_REST_BITS,
         path: str | os.PathLike = "<memory>") -> Packed:
    """Quantise `gaussians` (3DGS .ply frame) into SPZ's RUB frame."""
    path = Path(path)
    if version not in READ_VERSIONS:
        raise SplatFileError(path, f"cannot write SPZ version {version} (choose from 2, 3, 4)")
    if not (1 <= sh1_bits <= 8 and 1 <= sh_rest_bits <= 8):
        raise SplatFileError(path, f"SH bits must be 1..8, got {sh1_bits} and {sh_rest_bits}")
    check_savable(path, gaussians)
    if len(gaussians) == 0:
        raise SplatFileError(path, "cannot write an SPZ of zero Gaussians (Niantic's reader rejects it)")
    s = _frame_signs(COORD_RUB, path)  # RDF <-> RUB: its own inverse
    bits = _choose_fractional_bits(gaussians.means, path)
    positions = np.rint(gaussians.means.astype(np.float64) * (s * 2.0 ** bits)).astype(np.int32)
    scales = np.clip(np.rint((gaussians.log_scales.astype(np.float64) + 10.0) * 16.0), 0, 255)
    colors = np.rint(gaussians.sh[:, 0, :].astype(np.float64) * (COLOR_SCALE * 255.0) + 127.5)
    quats = gaussians.quats.astype(np.float64) * _quat_signs(s)
    rotations = _pack_rotations(quats[:, [1, 2, 3, 0]], version)
    rest = gaussians.sh[:, 1:, :] * _sh_signs(s)[:gaussians.sh.shape[1] - 1, None]
    sh = np.empty(rest.shape, np.uint8)
    sh[:, :3] = _quantise_sh(rest[:, :3], sh1_bits)
    sh[:, 3:] = _quantise_sh(rest[:, 3:], sh_rest_bits)
    return Packed(version=version, sh_degree=gaussians.degree, fractional_bits=bits,
                  antialiased=antialiased, coordinate_system=COORD_RUB, positions=positions,
                  alphas=encode_alpha(gaussians.opacity_logits),
                  colors=np.clip(colors, 0, 255).astype(np.uint8), scales=scales.astype(np.uint8),
                  rotations=rotations, sh=sh)


def _stream_bytes(packed: Packed) -> list[bytes]:
    n = len(packed)
    positions = packed.positions.astype("<i4").view(np.uint8).reshape(n, 3, 4)[..., :3]
    rotations = packed.rotations.astype("<u4") if packed.version >= 3 else packed.rotations
    return [np.ascontiguousarray(a).tobytes() for a in
            (positions, packed.alphas, packed.colors, packed.scales, rotations, packed.sh)]


def serialize(packed: Packed, path: str | os.PathLike = "<memory>") -> bytes:
    """The bytes of an SPZ file holding `packed` (in the container its version uses)."""
    path = Path(path)
    if packed.coordinate_system != COORD_RUB:
        raise SplatFileError(path, "cannot write: only the RUB frame is written (no extensions)")
    flags = FLAG_ANTIALIASED if packed.antialiased else 0
    streams = _stream_bytes(packed)
    n = len(packed)
    if packed.version < 4:
        header = _LEGACY_HEADER.pack(MAGIC, packed.version, n, packed.sh_degree,
                                     packed.fractional_bits, flags, 0)
        return gzip.compress(header + b"".join(streams), compresslevel=6, mtime=0)
    zstandard = _zstd(path, "write")
    compressor = zstandard.ZstdCompressor(level=ZSTD_LEVEL)
    raw = [s for s in streams if s]  # empty streams (SH of degree 0) are left out
    chunks = [compressor.compress(s) for s in raw]
    header = _NGSP_HEADER.pack(MAGIC, packed.version, n, packed.sh_degree, packed.fractional_bits,
                               flags, len(chunks), _NGSP_HEADER.size, bytes(12))
    toc = np.array([[len(c), len(r)] for c, r in zip(chunks, raw)], "<u8").tobytes()
    return header + toc + b"".join(chunks)


def save(gaussians: Gaussians, path: str | os.PathLike, version: int = LATEST_VERSION, *,
         antialiased: bool = False, sh1_bits: int = DEFAULT_SH1_BITS,
         sh_rest_bits: int = DEFAULT_SH_REST_BITS) -> None:
    """Write `gaussians` as SPZ (version 4 by default; 2 and 3 use gzip and need no zstandard)."""
    path = Path(path)
    packed = pack(gaussians, version, antialiased=antialiased, sh1_bits=sh1_bits,
                  sh_rest_bits=sh_rest_bits, path=path)
    data = serialize(packed, path)
    with os_errors(path), atomic_write(path) as f:
        f.write(data)
