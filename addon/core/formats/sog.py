"""PlayCanvas SOG version 2: read and write, as a folder (`meta.json` + WebP images) or a single
`.sog` file (a ZIP of the same files at its root).

Layout, as PlayCanvas specifies it (developer.playcanvas.com, "The SOG Format") and its
splat-transform tool writes it. Gaussian i lives at pixel (i % W, i // W) of every per-Gaussian
image (W x H >= count, the rest is padding); all images are 8-bit lossless WebP, read as raw bytes:
    means_l, means_u  RGB: low and high bytes of a 16-bit q per axis; n = lerp(mins, maxs, q/65535)
                      in the log domain, position = sign(n) (exp|n| - 1)
    quats             RGB: the three smallest components of the unit quaternion (w, x, y, z) as
                      (byte/255 * 2 - 1) / sqrt(2); A = 252 + index of the largest, which is
                      positive and derived from the unit length
    scales            RGB: indices into `scales.codebook` (256 log scales, shared by the 3 axes)
    sh0               RGB: indices into `sh0.codebook` (256 DC coefficients f_dc, shared);
                      A: opacity byte, sigmoid(logit) * 255
    shN_labels        RG: 16-bit palette index (R low byte) per Gaussian
    shN_centroids     the palette: 64 entries a row, entry e at pixel ((e % 64) * C + c, e // 64)
                      for coefficient c < C = 3, 8, 15 (bands 1..3), RGB indices into
                      `shN.codebook` (256 values shared by all higher-order coefficients)
`meta.json` also carries `count`, `antialias` (trained with the antialiased/Mip filter) and the
file names. The data is in the frame of the 3DGS `.ply` it was made from (splat-transform reads
and writes both without conversion), so no axes change here.

Writing: Gaussians are stored in Morton order of their positions (what splat-transform does: the
images compress better), so a round trip returns them reordered; `morton_order(means)` gives that
order. Image size W = 4 ceil(sqrt(n) / 4), H = 4 ceil(n / W / 4), as splat-transform.

Quantisation (write then read):
    position   within half a 16-bit step of the per-axis range in the log domain, |dn| <=
               (max - min) / 131070, so |dx| <= (|x| + 1) |dn| to first order: 3.7e-5 (|x| + 1)
               for a scene within +-10 units
    rotation   the three stored components within sqrt(2)/255/2 = 2.8e-3, the derived one
               within about 4e-3 (plus the sign of q, which is the same rotation)
    log scale, DC colour  the nearest of 256 codebook entries, chosen by optimal 1D k-means
               (`codebook.scalar_codebook`): no fixed bound, errors are reported by the tests
    opacity    within 0.5/255 (byte 0 and 255 read as opacity 1e-6 and 1 - 1e-6, as
               splat-transform)
    SH rest    the palette entry (k-means over the Gaussians' higher-order coefficients with up to
               65536 entries), each value then the nearest of 256 codebook entries
The image bytes themselves round-trip exactly (lossless WebP), except RGB under an opacity
byte of 0, which libwebp drops: such a Gaussian is invisible (opacity < 1/510) and reads back
with colour codebook[0].
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..gaussians import Gaussians, logit, sigmoid
from ..atomic import atomic_write
from ..formats_common import webp
from ..formats_common.codebook import palette, scalar_codebook
from ..formats_common.contained import contained_file, is_contained_name, read_regular, unrepresentable
from ..formats_common.errors import SplatFileError, check_decoded, check_savable
from ..formats_common.json_file import malformed, parse_object
from ..formats_common.limits import check_expansion, check_gaussian_count
from ..formats_common.morton import morton_order
from ..formats_common.quaternions import smallest_three

__all__ = ["load", "load_with_info", "save", "SogInfo", "read_info", "morton_order", "MAX_COUNT", "VERSION"]

VERSION = 2
MAX_COUNT = 1 << 27  # 134M Gaussians: beyond any real scene; bounds what a header can ask for
MAX_PALETTE = 65536
OPACITY_EPS = 1e-6  # opacity bytes 0 and 255 decode to these (as splat-transform's reader)
COEFFS = {1: 3, 2: 8, 3: 15}  # SH bands -> higher-order coefficients per colour channel
MAX_MEMBER_BYTES = 1 << 30  # one image or meta.json inside a .sog bundle
MAX_META_BYTES = 16 << 20
# What a .sog may unpack in total: its members are WebP images (already compressed, so a ZIP
# barely shrinks them: about 1:1) and one small meta.json; 16 times the bundle's size is far
# beyond any real one, and bounds a zip bomb's unpacking (to disk) by what the file can justify.
MAX_UNPACK_RATIO = 16
UNPACK_SLACK = 4 << 20
GENERATOR = "Gaussian Splatting for Blender"


@dataclass(frozen=True)
class SogInfo:
    count: int
    sh_degree: int
    antialiased: bool
    palette_size: int  # 0 without higher-order SH


# ------------------------------------------------------------------------------------------
# meta.json


def _fail(path: Path, problem: str) -> SplatFileError:
    return SplatFileError(path, problem)


def _parse_meta(path: Path, text: bytes) -> dict[str, Any]:
    meta = parse_object(path, text, "meta.json")
    version = meta.get("version")
    if version is None:
        raise _fail(path, "SOG version 1 (meta.json without 'version') is not supported; "
                          "re-export it with a current splat-transform")
    if version != VERSION:
        raise _fail(path, f"unsupported SOG version {version!r}: expected {VERSION}")
    return meta


def _field(path: Path, meta: dict, *keys: str) -> Any:
    value: Any = meta
    for key in keys:
        if not isinstance(value, dict) or key not in value:
            raise _fail(path, f"missing {'.'.join(keys)!r} in meta.json")
        value = value[key]
    return value


def _integer(path: Path, value: Any, name: str, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value != int(value) \
            or not lo <= value <= hi:
        raise _fail(path, f"bad {name} {value!r} in meta.json: expected an integer in [{lo}, {hi}]")
    return int(value)


def _numbers(path: Path, value: Any, name: str, length: int | None = None) -> np.ndarray:
    try:
        array = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        array = None
    if array is None or array.ndim != 1 or (length is not None and len(array) != length) \
            or len(array) == 0 or not np.isfinite(array).all():
        want = f"{length} finite numbers" if length else "a list of finite numbers"
        raise _fail(path, f"bad {name!r} in meta.json: expected {want}")
    return array


def _files(path: Path, meta: dict, key: str, count: int) -> list[str]:
    names = _field(path, meta, key, "files")
    if not isinstance(names, list) or len(names) < count or not all(isinstance(n, str) for n in names[:count]):
        raise _fail(path, f"bad {key}.files in meta.json: expected {count} file names")
    for name in names[:count]:
        if not is_contained_name(name):
            problem = unrepresentable(name) or "must be a relative path inside the SOG folder"
            raise _fail(path, f"bad file name {name[:200]!r} in {key}.files of meta.json: {problem}")
    return names[:count]


# ------------------------------------------------------------------------------------------
# Reading


class _Source:
    """Where the images are: a folder, or a .sog bundle unpacked member by member on demand.
    Member names are judged by `contained.contained_file` (folder) or `is_contained_name`
    (bundle); a bundle's members go to scratch files named here, never after the member, and
    all of them together unpack to at most `MAX_UNPACK_RATIO` times the bundle's size."""

    def __init__(self, path: Path, folder: Path, bundle: zipfile.ZipFile | None = None,
                 scratch: Path | None = None, budget: int = 0, size: int = 0) -> None:
        self.path, self.folder, self.bundle, self.scratch = path, folder, bundle, scratch
        self.size = size  # a bundle's bytes
        self.meta_name = "meta.json" if bundle is not None else path.name
        self.budget = budget  # bytes a bundle may still unpack
        self.unpacked: dict[str, Path] = {}

    def meta_bytes(self) -> bytes:
        if self.bundle is None:
            return read_regular(self.path, self.path, "meta.json", MAX_META_BYTES)
        return self._unpack("meta.json", MAX_META_BYTES)

    def _unpack(self, name: str, limit: int) -> bytes:
        if not is_contained_name(name):
            problem = unrepresentable(name) or "must be a relative path inside the bundle"
            raise _fail(self.path, f"bad member name {name[:200]!r} in the .sog bundle: {problem}")
        try:
            info = self.bundle.getinfo(name)
        except KeyError:
            raise _fail(self.path, f"missing {name!r} in the .sog bundle") from None
        limit = min(limit, self.budget)
        if info.file_size > limit:
            raise _fail(self.path, f"{name} in the bundle unpacks to {info.file_size} bytes, more than "
                                   f"the {limit} this bundle can justify")
        try:
            with self.bundle.open(info) as f:
                data = f.read(limit + 1)
        except (zipfile.BadZipFile, zlib.error, OSError, EOFError, RuntimeError, NotImplementedError,
                ValueError) as e:
            raise _fail(self.path, f"cannot unpack {name}: {e}") from None
        if len(data) > limit:
            raise _fail(self.path, f"{name} in the bundle unpacks to more than {limit} bytes")
        self.budget -= len(data)
        return data

    def image_path(self, name: str) -> Path:
        if self.bundle is None:
            return contained_file(self.folder, name, self.path, "image")
        if name not in self.unpacked:
            target = self.scratch / f"member-{len(self.unpacked)}.webp"
            data = self._unpack(name, MAX_MEMBER_BYTES)
            try:
                target.write_bytes(data)
            except OSError as e:
                raise _fail(self.path, f"cannot unpack {name} to a temporary file: "
                                       f"{e.strerror or e}") from None
            self.unpacked[name] = target
        return self.unpacked[name]

    def file_bytes(self, meta_bytes: int, names: list[str]) -> int:
        """What the SOG is made of, in bytes: a bundle's size, or meta.json and its images."""
        if self.bundle is not None:
            return self.size
        total = meta_bytes
        for name in set(names):
            try:
                total += self.image_path(name).stat().st_size
            except OSError as e:
                raise _fail(self.path, f"cannot read image {name}: {e.strerror or e}") from None
        return total

    def read_size(self, name: str) -> tuple[int, int, int]:
        return webp.read_size(self.image_path(name), self.path, name)

    def read_rgba(self, name: str) -> np.ndarray:
        return webp.read_rgba(self.image_path(name), self.path, name)


def _image(source: _Source, name: str, count: int, per_gaussian: bool = True) -> np.ndarray:
    """An image's pixels (H*W, 4) after checking its size from the header."""
    width, height, _ = source.read_size(name)
    if per_gaussian and width * height < count:
        raise _fail(source.path, f"image {name} is {width}x{height}: too small for {count} Gaussians")
    if per_gaussian and width * height > 4 * count + 64 * (width + height) + 4096:
        # A writer pads at most a few rows; far more pixels than Gaussians is a corrupt header
        # (or a count that does not belong to these images), not worth decoding.
        raise _fail(source.path, f"image {name} is {width}x{height}: far larger than {count} Gaussians need")
    pixels = source.read_rgba(name)
    if pixels.shape[:2] != (height, width):
        raise _fail(source.path, f"image {name} decodes to {pixels.shape[1]}x{pixels.shape[0]}, "
                                 f"its header says {width}x{height}")
    return pixels.reshape(-1, 4)


def _codebook(path: Path, meta: dict, key: str) -> np.ndarray:
    book = _numbers(path, _field(path, meta, key, "codebook"), f"{key}.codebook")
    if len(book) > 256:
        raise _fail(path, f"bad {key}.codebook in meta.json: {len(book)} entries, at most 256")
    if np.abs(book).max() > np.finfo(np.float32).max:
        raise _fail(path, f"bad {key}.codebook in meta.json: values beyond float32")
    return book


def _lookup(path: Path, book: np.ndarray, indices: np.ndarray, what: str) -> np.ndarray:
    if len(book) < 256 and indices.size and int(indices.max()) >= len(book):
        raise _fail(path, f"{what} index {int(indices.max())} beyond its {len(book)}-entry codebook")
    return book[indices]


def _decode_means(path: Path, meta: dict, source: _Source, count: int) -> np.ndarray:
    mins = _numbers(path, _field(path, meta, "means", "mins"), "means.mins", 3)
    maxs = _numbers(path, _field(path, meta, "means", "maxs"), "means.maxs", 3)
    low_name, high_name = _files(path, meta, "means", 2)
    low = _image(source, low_name, count)[:count, :3].astype(np.float64)
    high = _image(source, high_name, count)[:count, :3].astype(np.float64)
    n = mins + (maxs - mins) * ((high * 256.0 + low) / 65535.0)
    with np.errstate(over="ignore"):
        means = np.sign(n) * np.expm1(np.abs(n))
    if not np.isfinite(means).all() or np.abs(means).max(initial=0.0) > np.finfo(np.float32).max:
        raise _fail(path, "means.mins/maxs decode to positions beyond float32")
    return means


def _decode_quats(path: Path, meta: dict, source: _Source, count: int) -> np.ndarray:
    pixels = _image(source, _files(path, meta, "quats", 1)[0], count)[:count]
    largest = pixels[:, 3].astype(np.intp) - 252
    bad = (largest < 0) | (largest > 3)
    if bad.any():
        raise _fail(path, f"quats image: {int(bad.sum())} Gaussians have a mode byte outside 252..255")
    small = (pixels[:, :3].astype(np.float64) / 255.0 * 2.0 - 1.0) / math.sqrt(2.0)
    derived = np.sqrt(np.maximum(0.0, 1.0 - np.einsum("ij,ij->i", small, small)))
    slot = np.arange(4)
    pick = np.minimum(slot - (slot > largest[:, None]), 2)  # slot k takes small[k] before, small[k-1] after
    quats = np.take_along_axis(small, pick, axis=1)
    quats[np.arange(count), largest] = derived
    return quats


def _decode_scales(path: Path, meta: dict, source: _Source, count: int) -> np.ndarray:
    book = _codebook(path, meta, "scales")
    pixels = _image(source, _files(path, meta, "scales", 1)[0], count)[:count, :3]
    return _lookup(path, book, pixels, "scales")


def _decode_sh0(path: Path, meta: dict, source: _Source, count: int) -> tuple[np.ndarray, np.ndarray]:
    book = _codebook(path, meta, "sh0")
    pixels = _image(source, _files(path, meta, "sh0", 1)[0], count)[:count]
    dc = _lookup(path, book, pixels[:, :3], "sh0")
    opacity = np.clip(pixels[:, 3] / 255.0, OPACITY_EPS, 1.0 - OPACITY_EPS)
    return dc, logit(opacity)


def _decode_sh_rest(path: Path, meta: dict, source: _Source, count: int) -> np.ndarray:
    """(count, C, 3) higher-order coefficients, coefficient-major like Gaussians.sh[:, 1:]."""
    bands = _integer(path, _field(path, meta, "shN", "bands"), "shN.bands", 1, 3)
    entries = _integer(path, _field(path, meta, "shN", "count"), "shN.count", 1, MAX_PALETTE)
    book = _codebook(path, meta, "shN")
    centroid_name, label_name = _files(path, meta, "shN", 2)
    coeffs = COEFFS[bands]
    width, height, _ = source.read_size(centroid_name)
    rows = -(-entries // 64)
    if width != 64 * coeffs or not rows <= height <= -(-MAX_PALETTE // 64):
        raise _fail(path, f"image {centroid_name} is {width}x{height}; a {entries}-entry palette of "
                          f"{bands} bands needs {64 * coeffs}x{rows}")
    centroids = _image(source, centroid_name, 0, per_gaussian=False)
    # Entry e, coefficient c at pixel (e % 64) * coeffs + c of row e // 64: rows of 64 entries.
    centroids = centroids.reshape(height, 64, coeffs, 4)[..., :3].reshape(height * 64, coeffs, 3)[:entries]
    centroids = _lookup(path, book, centroids, "shN")
    labels_px = _image(source, label_name, count)[:count]
    labels = labels_px[:, 0].astype(np.intp) | (labels_px[:, 1].astype(np.intp) << 8)
    if labels.size and int(labels.max()) >= entries:
        raise _fail(path, f"shN label {int(labels.max())} beyond the {entries}-entry palette")
    return centroids[labels]


def _check_expansion(path: Path, meta: dict, source: _Source, count: int, meta_bytes: int) -> None:
    """The Gaussians meta.json declares against the bytes of the SOG (meta.json and every image
    it names), before any image is decoded: uniform lossless WebPs of a few hundred bytes can
    declare 3162x3162 pixels each (issue 33's 17 KB folder asked for 10M Gaussians). Checked for
    the SOG as a whole, not per image: an image of constant bytes (untrained rotations, one
    SH palette entry) legitimately compresses to nearly nothing."""
    names = _files(path, meta, "means", 2) + _files(path, meta, "quats", 1) + \
        _files(path, meta, "scales", 1) + _files(path, meta, "sh0", 1)
    degree = 0
    if meta.get("shN"):
        degree = _integer(path, _field(path, meta, "shN", "bands"), "shN.bands", 1, 3)
        names += _files(path, meta, "shN", 2)
    check_expansion(path, count, degree, source.file_bytes(meta_bytes, names))


def _decode(path: Path, source: _Source) -> tuple[Gaussians, SogInfo]:
    text = source.meta_bytes()
    meta = _parse_meta(path, text)
    count = _integer(path, _field(path, meta, "count"), "count", 0, MAX_COUNT)
    check_gaussian_count(path, count)
    _check_expansion(path, meta, source, count, len(text))
    means = _decode_means(path, meta, source, count)
    quats = _decode_quats(path, meta, source, count)
    log_scales = _decode_scales(path, meta, source, count)
    dc, logits = _decode_sh0(path, meta, source, count)
    rest = _decode_sh_rest(path, meta, source, count) if meta.get("shN") else np.zeros((count, 0, 3))
    sh = np.concatenate([dc[:, None, :], rest], axis=1)
    with np.errstate(over="ignore"):
        gaussians = Gaussians(means, log_scales, quats, logits, sh)
    check_decoded(path, gaussians)  # every input was checked; this is the net under those checks
    info = SogInfo(count, gaussians.degree, bool(meta.get("antialias", False)),
                   int(meta["shN"]["count"]) if meta.get("shN") else 0)
    return gaussians, info


def _with_source(path: str | os.PathLike, action: Callable[[Path, _Source], Any]) -> Any:
    """Run `action` on the SOG at `path`: a `.sog` bundle, a `meta.json`, or a folder holding one."""
    path = Path(path)
    if path.is_dir():
        path = path / "meta.json"
    if path.suffix.lower() != ".sog":
        if not path.is_file():
            raise _fail(path, "no such SOG meta.json")
        with malformed(path, "SOG"):
            return action(path, _Source(path, path.parent))
    try:
        size = path.stat().st_size
        if not path.is_file():
            raise _fail(path, "not a regular file")
        bundle = zipfile.ZipFile(path)
    except FileNotFoundError:
        raise _fail(path, "no such file") from None
    except (zipfile.BadZipFile, zlib.error, OSError, EOFError, ValueError, NotImplementedError,
            RuntimeError) as e:
        raise _fail(path, f"not a .sog bundle (a ZIP file): {e}") from None
    budget = MAX_UNPACK_RATIO * size + UNPACK_SLACK
    with bundle, malformed(path, "SOG"):
        try:
            scratch = tempfile.TemporaryDirectory(prefix="sog-")
        except OSError as e:
            raise _fail(path, f"cannot make a temporary folder to unpack into: {e.strerror or e}") from None
        with scratch:
            return action(path, _Source(path, path.parent, bundle, Path(scratch.name), budget, size))


def load(path: str | os.PathLike) -> Gaussians:
    """Read a SOG (`.sog` bundle, `meta.json`, or its folder) into `Gaussians`."""
    return load_with_info(path)[0]


def load_with_info(path: str | os.PathLike) -> tuple[Gaussians, SogInfo]:
    """`load`, and what meta.json says about the data (the antialiased flag among it)."""
    return _with_source(path, _decode)


def read_info(path: str | os.PathLike) -> SogInfo:
    """What a SOG holds, from meta.json alone (count, SH degree, antialiased flag)."""
    def info(p: Path, source: _Source) -> SogInfo:
        meta = _parse_meta(p, source.meta_bytes())
        count = _integer(p, _field(p, meta, "count"), "count", 0, MAX_COUNT)
        check_gaussian_count(p, count)
        sh = meta.get("shN")
        bands = _integer(p, _field(p, meta, "shN", "bands"), "shN.bands", 1, 3) if sh else 0
        return SogInfo(count, bands, bool(meta.get("antialias", False)), int(sh["count"]) if sh else 0)
    return _with_source(path, info)


def load_chunk(meta_path: Path) -> Gaussians:
    """One chunk of a LOD set: a folder SOG whose meta.json is `meta_path` (already judged by
    `contained.contained_file`); errors name it."""
    with malformed(meta_path, "SOG"):
        return _decode(meta_path, _Source(meta_path, meta_path.parent))[0]


def chunk_count(meta_path: Path) -> int:
    """How many Gaussians a LOD chunk holds, from its meta.json alone."""
    with malformed(meta_path, "SOG"):
        meta = _parse_meta(meta_path, _Source(meta_path, meta_path.parent).meta_bytes())
        return _integer(meta_path, _field(meta_path, meta, "count"), "count", 0, MAX_COUNT)


# ------------------------------------------------------------------------------------------
# Writing


def image_size(count: int) -> tuple[int, int]:
    """(W, H) of the per-Gaussian images: splat-transform's layout, at least 4x4."""
    width = max(4, 4 * math.ceil(math.sqrt(count) / 4))
    height = max(4, 4 * math.ceil(count / width / 4))
    return width, height


def palette_size(count: int) -> int:
    """splat-transform's SH palette size: a power of two times 1024, at most 65536, for counts
    of 1024 and up; every Gaussian its own entry below that."""
    if count < 1024:
        return count
    return min(64, 2 ** int(math.floor(math.log2(count / 1024)))) * 1024


def _as_image(rows: np.ndarray, width: int, height: int) -> np.ndarray:
    """(n, 4) uint8 rows -> (H, W, 4) image, padding transparent black."""
    image = np.zeros((width * height, 4), np.uint8)
    image[:len(rows)] = rows
    return image.reshape(height, width, 4)


def _rows(*channels: np.ndarray, alpha: np.ndarray | int = 255) -> np.ndarray:
    n = len(channels[0])
    rows = np.empty((n, 4), np.uint8)
    for i, c in enumerate(channels):
        rows[:, i] = c
    rows[:, 3] = alpha
    return rows


def _encode_means(means: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict]:
    n = np.sign(means) * np.log1p(np.abs(means))
    mins, maxs = (n.min(axis=0), n.max(axis=0)) if len(n) else (np.zeros(3), np.zeros(3))
    span = np.where(maxs > mins, maxs - mins, 1.0)
    q = np.clip(np.rint((n - mins) / span * 65535.0), 0, 65535).astype(np.uint16)
    low, high = (q & 0xFF).astype(np.uint8), (q >> 8).astype(np.uint8)
    return _rows(*low.T), _rows(*high.T), {"mins": mins.tolist(), "maxs": maxs.tolist()}


def _encode_quats(quats: np.ndarray) -> np.ndarray:
    largest, small = smallest_three(quats)
    bytes_ = np.clip(np.rint((small * math.sqrt(2.0) * 0.5 + 0.5) * 255.0), 0, 255).astype(np.uint8)
    return _rows(*bytes_.T, alpha=(252 + largest).astype(np.uint8))


def _encode_sh_rest(rest: np.ndarray, degree: int, write: Callable[[str, np.ndarray], None],
                    width: int, height: int) -> dict:
    n, coeffs = len(rest), COEFFS[degree]
    size = palette_size(n)
    centroids, labels = palette(rest.reshape(n, coeffs * 3), size)
    book, codes = scalar_codebook(centroids)
    entries = len(centroids)
    rows = -(-entries // 64)
    image = np.zeros((rows * 64, coeffs, 4), np.uint8)
    image[:entries, :, :3] = codes.reshape(entries, coeffs, 3)
    image[:entries, :, 3] = 255
    write("shN_centroids.webp", image.reshape(rows, 64 * coeffs, 4))
    write("shN_labels.webp", _as_image(_rows(labels & 0xFF, labels >> 8, np.zeros(n, np.uint8)), width, height))
    return {"count": entries, "bands": degree, "codebook": book.tolist(),
            "files": ["shN_centroids.webp", "shN_labels.webp"]}


def _write_folder(gaussians: Gaussians, folder: Path, antialiased: bool) -> None:
    """All files of a SOG into `folder` (meta.json last)."""
    g = gaussians.subset(morton_order(gaussians.means))
    n = len(g)
    width, height = image_size(n)

    def write(name: str, image: np.ndarray) -> None:
        webp.write_rgba(folder / name, image)

    low, high, bounds = _encode_means(g.means.astype(np.float64))
    write("means_l.webp", _as_image(low, width, height))
    write("means_u.webp", _as_image(high, width, height))
    write("quats.webp", _as_image(_encode_quats(g.quats), width, height))
    scale_book, scale_codes = scalar_codebook(g.log_scales)
    write("scales.webp", _as_image(_rows(*scale_codes.T), width, height))
    dc_book, dc_codes = scalar_codebook(g.sh[:, 0, :])
    opacity = np.rint(sigmoid(g.opacity_logits) * 255.0)
    write("sh0.webp", _as_image(_rows(*dc_codes.T, alpha=opacity.astype(np.uint8)), width, height))
    meta: dict[str, Any] = {
        "version": VERSION, "asset": {"generator": GENERATOR}, "count": n, "antialias": bool(antialiased),
        "means": {**bounds, "files": ["means_l.webp", "means_u.webp"]},
        "scales": {"codebook": scale_book.tolist(), "files": ["scales.webp"]},
        "quats": {"files": ["quats.webp"]},
        "sh0": {"codebook": dc_book.tolist(), "files": ["sh0.webp"]},
    }
    if g.degree > 0 and n > 0:
        meta["shN"] = _encode_sh_rest(g.sh[:, 1:, :], g.degree, write, width, height)
    (folder / "meta.json").write_text(json.dumps(meta), encoding="utf-8")


def save(gaussians: Gaussians, path: str | os.PathLike, *, antialiased: bool = False) -> None:
    """Write a SOG: a `.sog` bundle, or a folder form when `path` is a `meta.json` (the images are
    written beside it). Atomic: a `.sog` appears whole; a folder's meta.json is replaced last,
    after every image it names is in place."""
    path = Path(path)
    check_savable(path, gaussians)
    if len(gaussians) > MAX_COUNT:
        raise _fail(path, f"cannot save {len(gaussians)} Gaussians in one SOG (at most {MAX_COUNT})")
    bundle = path.suffix.lower() == ".sog"
    if not bundle and path.name.lower() != "meta.json":
        raise _fail(path, "a SOG is saved as a .sog file or as a folder's meta.json")
    try:
        parent = path.parent
        parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(prefix=".sog-", dir=parent) as scratch:
            scratch = Path(scratch)
            _write_folder(gaussians, scratch, antialiased)
            names = sorted(p.name for p in scratch.iterdir())
            if bundle:
                with atomic_write(path) as f, zipfile.ZipFile(f, "w", zipfile.ZIP_STORED) as archive:
                    for name in ["meta.json"] + [n for n in names if n != "meta.json"]:
                        archive.write(scratch / name, name)
            else:
                for name in names:
                    if name != "meta.json":
                        os.replace(scratch / name, parent / name)
                os.replace(scratch / "meta.json", path)
    except OSError as e:
        raise _fail(path, f"cannot write: {e.strerror or e}") from None

