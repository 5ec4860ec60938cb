"""glTF 2.0 with KHR_gaussian_splatting (Khronos, release candidate, 2026): read and write
`.glb` and `.gltf`.

Per the extension (KhronosGroup/glTF, extensions/2.0/Khronos/KHR_gaussian_splatting): a mesh
primitive with mode POINTS (0) and the `KHR_gaussian_splatting` extension object (`kernel`
"ellipse" and `colorSpace` required) holds one Gaussian per vertex:
    POSITION                                  VEC3 float: the mean
    KHR_gaussian_splatting:ROTATION           VEC4 unit quaternion x, y, z, w (float, or normalised
                                              byte/short)
    KHR_gaussian_splatting:SCALE              VEC3 linear standard deviations (>= 0; float, or
                                              ubyte/ushort, normalised or not)
    KHR_gaussian_splatting:OPACITY            SCALAR in [0, 1] (float, or normalised ubyte/ushort)
    KHR_gaussian_splatting:SH_DEGREE_l_COEF_n VEC3 float RGB, n = 0..2l for m = -l..l: the 3DGS
                                              coefficient order, so SH_DEGREE_l_COEF_n is
                                              Gaussians.sh[:, l*l + n]
    COLOR_0 (optional fallback for point viewers) linear RGB + opacity; written, ignored on read.
The kernel is the 3DGS one the renderer draws; `colorSpace` is written "srgb_rec709_display"
(Gaussians trained on photos, as ours are); files in "lin_rec709_display" load unchanged.

Frame: glTF is y up, x right, +z towards the viewer (RUB); `Gaussians` are in the 3DGS `.ply`
frame (RDF). Writing turns the scene half a turn about x (`frames.rdf_to_rub`: y and z negate),
reading turns it back, then applies the node's global transform when it is not the identity
(the Blender side's own y-up to z-up conversion is not done here). Niantic's SPZ uses the same
mapping, so an SPZ and a glTF of one scene load identically.

The SPZ-compressed form (KHR_gaussian_splatting_compression_spz_2) is a draft: refused with a
clear error, as is any other required extension.

Quantisation: none on write (float32): means and SH are bit-exact after a round trip; log scales
go through exp and log in float64 (within a float32 rounding); opacity through the sigmoid: logits
beyond +-16.6 come back as +-16.6 (float32 holds no opacity closer to 1), opacity within 6e-8;
quaternions come back normalised (same rotation; w >= 0 is not enforced).
"""

from __future__ import annotations

import base64
import binascii
import json
import os
import struct
import urllib.parse
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..colour import srgb_decode
from ..gaussians import Gaussians, log_scales_of, logit, scales_of, sigmoid
from ..sh import dc_colour
from ..transform import transform_gaussians
from ..atomic import atomic_write
from ..formats_common.assemble import Assembly
from ..formats_common.contained import contained_file, read_regular
from ..formats_common.errors import SplatFileError, check_savable, os_errors
from ..formats_common.frames import rdf_to_rub
from ..formats_common.json_file import malformed, parse_object
from ..formats_common.limits import check_expansion, check_gaussian_count
from ..formats_common.quaternions import unit_quaternions

__all__ = ["load", "save", "EXTENSION", "SPZ_EXTENSION", "attribute_names"]

EXTENSION = "KHR_gaussian_splatting"
SPZ_EXTENSION = "KHR_gaussian_splatting_compression_spz_2"
PREFIX = EXTENSION + ":"
GLB_MAGIC = 0x46546C67  # "glTF"
CHUNK_JSON = 0x4E4F534A
CHUNK_BIN = 0x004E4942
FLOAT, BYTE, UBYTE, SHORT, USHORT = 5126, 5120, 5121, 5122, 5123
COMPONENTS = {FLOAT: ("<f4", 4), BYTE: ("<i1", 1), UBYTE: ("<u1", 1), SHORT: ("<i2", 2), USHORT: ("<u2", 2)}
WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
ARRAY_BUFFER = 34962
MAX_JSON_BYTES = 1 << 31  # a .gltf with its buffer embedded as base64 (about 4/3 of a .glb)
MAX_NODE_DEPTH = 64
GENERATOR = "Gaussian Splatting for Blender"


def attribute_names(degree: int) -> list[str]:
    """The SH attribute semantics of degrees 0..`degree`, in Gaussians.sh order."""
    return [f"{PREFIX}SH_DEGREE_{band}_COEF_{n}" for band in range(degree + 1)
            for n in range(2 * band + 1)]


# ------------------------------------------------------------------------------------------
# Writing


@dataclass
class _Blob:
    """The binary buffer under construction: 4-byte aligned views and their accessors."""

    parts: list[bytes]
    views: list[dict]
    accessors: list[dict]
    size: int = 0

    def add(self, data: np.ndarray, component: int, kind: str, *, normalized: bool = False,
            bounds: bool = False) -> int:
        raw = np.ascontiguousarray(data).tobytes()
        self.views.append({"buffer": 0, "byteOffset": self.size, "byteLength": len(raw), "target": ARRAY_BUFFER})
        accessor: dict[str, Any] = {"bufferView": len(self.views) - 1, "componentType": component,
                                    "count": len(data), "type": kind}
        if normalized:
            accessor["normalized"] = True
        if bounds and len(data):
            accessor["min"] = data.min(axis=0).astype(float).tolist()
            accessor["max"] = data.max(axis=0).astype(float).tolist()
        self.accessors.append(accessor)
        pad = (-len(raw)) % 4
        self.parts.append(raw + b"\0" * pad)
        self.size += len(raw) + pad
        return len(self.accessors) - 1


def _document(gaussians: Gaussians) -> tuple[dict, bytes]:
    g = rdf_to_rub(gaussians)
    blob = _Blob([], [], [])
    attributes: dict[str, int] = {}
    attributes["POSITION"] = blob.add(g.means.astype("<f4"), FLOAT, "VEC3", bounds=True)
    q = unit_quaternions(g.quats)
    attributes[f"{PREFIX}ROTATION"] = blob.add(q[:, [1, 2, 3, 0]].astype("<f4"), FLOAT, "VEC4")
    attributes[f"{PREFIX}SCALE"] = blob.add(scales_of(g.log_scales).astype("<f4"), FLOAT, "VEC3")
    opacity = sigmoid(g.opacity_logits)
    attributes[f"{PREFIX}OPACITY"] = blob.add(opacity.astype("<f4"), FLOAT, "SCALAR")
    for index, name in enumerate(attribute_names(g.degree)):
        attributes[name] = blob.add(g.sh[:, index, :].astype("<f4"), FLOAT, "VEC3")
    # Fallback colour for viewers without the extension: linear, as glTF's COLOR_0 is.
    srgb = np.clip(dc_colour(g.sh[:, 0, :].astype(np.float64)), 0.0, 1.0)
    rgba = np.concatenate([srgb_decode(srgb), opacity[:, None]], axis=1)
    attributes["COLOR_0"] = blob.add(np.rint(rgba * 255.0).astype(np.uint8), UBYTE, "VEC4", normalized=True)
    document = {
        "asset": {"version": "2.0", "generator": GENERATOR},
        "extensionsUsed": [EXTENSION],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "gaussians"}],
        "meshes": [{"primitives": [{
            "attributes": attributes, "mode": 0,
            "extensions": {EXTENSION: {"kernel": "ellipse", "colorSpace": "srgb_rec709_display",
                                       "projection": "perspective", "sortingMethod": "cameraDistance"}},
        }]}],
        "buffers": [{"byteLength": blob.size}],
        "bufferViews": blob.views,
        "accessors": blob.accessors,
    }
    return document, b"".join(blob.parts)


def save(gaussians: Gaussians, path: str | os.PathLike) -> None:
    """Write `gaussians` as `.glb` (binary) or `.gltf` (JSON, the buffer embedded as a data URI),
    atomically."""
    path = Path(path)
    check_savable(path, gaussians)
    document, binary = _document(gaussians)
    if path.suffix.lower() == ".gltf":
        encoded = base64.b64encode(binary).decode("ascii")
        document["buffers"][0]["uri"] = "data:application/octet-stream;base64," + encoded
        payload = json.dumps(document).encode("utf-8")
    else:
        text = json.dumps(document).encode("utf-8")
        text += b" " * ((-len(text)) % 4)
        total = 12 + 8 + len(text) + (8 + len(binary) if binary else 0)
        if total >= 1 << 32:
            raise SplatFileError(path, "too many Gaussians for one .glb (over 4 GiB)")
        payload = struct.pack("<III", GLB_MAGIC, 2, total) + struct.pack("<II", len(text), CHUNK_JSON) + text
        if binary:
            payload += struct.pack("<II", len(binary), CHUNK_BIN) + binary
    with os_errors(path), atomic_write(path) as f:
        f.write(payload)


# ------------------------------------------------------------------------------------------
# Reading




def _parse_json(path: Path, text: bytes) -> dict:
    return parse_object(path, text, "the glTF document")


def _split_glb(path: Path, data: bytes) -> tuple[dict, bytes | None]:
    if len(data) < 20:
        raise SplatFileError(path, "truncated .glb: shorter than its headers")
    magic, version, length = struct.unpack_from("<III", data)
    if magic != GLB_MAGIC:
        raise SplatFileError(path, "not a .glb file (bad magic)")
    if version != 2:
        raise SplatFileError(path, f"unsupported glTF container version {version}: expected 2")
    if length > len(data):
        raise SplatFileError(path, f"truncated .glb: header says {length} bytes, the file has {len(data)}")
    view = memoryview(data)
    json_chunk, binary, at = None, None, 12
    while at + 8 <= length:
        size, kind = struct.unpack_from("<II", data, at)
        if at + 8 + size > length:
            raise SplatFileError(path, f"truncated .glb: a chunk of {size} bytes runs past the end")
        if json_chunk is None:
            if kind != CHUNK_JSON:
                break
            json_chunk = data[at + 8:at + 8 + size]
        elif kind == CHUNK_BIN and binary is None:
            binary = view[at + 8:at + 8 + size]  # shared, not copied
        at += 8 + size
    if json_chunk is None:
        raise SplatFileError(path, "bad .glb: the first chunk is not JSON")
    return _parse_json(path, json_chunk), binary


def _buffers(path: Path, document: dict, binary: memoryview | None) -> tuple[list[memoryview], int]:
    """Every buffer's bytes, shared where they can be: a file named by several buffers is read
    once (as much of it as the longest needs); external files are judged by
    `contained.contained_file` (inside the glTF's folder, links followed, regular files). And
    how many bytes were read from external files."""
    wanted: list[tuple[int, Any]] = []
    longest: dict[Path, int] = {}
    for i, buffer in enumerate(_list(path, document, "buffers")):
        if not isinstance(buffer, dict):
            raise SplatFileError(path, f"bad glTF: buffers[{i}] is not an object")
        length = _int(path, buffer.get("byteLength"), f"buffers[{i}].byteLength")
        uri = buffer.get("uri")
        if isinstance(uri, str) and not uri.startswith("data:"):
            what = f"buffers[{i}].uri"
            file = contained_file(path.parent, urllib.parse.unquote(uri), path, what)
            size = file.stat().st_size
            if size < length:
                raise SplatFileError(path, f"buffers[{i}] declares {length} bytes, {uri!r} holds {size}")
            uri = file.resolve()
            longest[uri] = max(longest.get(uri, 0), length)
        wanted.append((length, uri))
    files = {file: memoryview(read_regular(file, path, f"buffer file {file.name!r}", first=limit))
             for file, limit in longest.items()}
    buffers = []
    for i, (length, uri) in enumerate(wanted):
        if uri is None:
            if i != 0 or binary is None:
                raise SplatFileError(path, f"buffers[{i}] has no uri and there is no .glb binary chunk")
            data = binary
        elif isinstance(uri, Path):
            data = files[uri]
        elif not isinstance(uri, str):
            raise SplatFileError(path, f"bad buffers[{i}].uri")
        else:  # a data URI: its bytes are in the document, decoded once
            try:
                data = memoryview(base64.b64decode(uri.split(",", 1)[1], validate=True))
            except (IndexError, ValueError, binascii.Error):
                raise SplatFileError(path, f"bad data URI in buffers[{i}]") from None
        if len(data) < length:
            raise SplatFileError(path, f"buffers[{i}] declares {length} bytes, holds {len(data)}")
        buffers.append(data[:length])
    return buffers, sum(len(data) for data in files.values())


def _list(path: Path, document: dict, key: str) -> list:
    value = document.get(key, [])
    if not isinstance(value, list):
        raise SplatFileError(path, f"bad glTF: {key!r} is not a list")
    return value


def _int(path: Path, value: Any, name: str, hi: int = 1 << 62) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= hi:
        raise SplatFileError(path, f"bad glTF: {name} = {value!r}, expected an integer in [0, {hi}]")
    return value


def _item(path: Path, document: dict, key: str, index: Any) -> dict:
    items = _list(path, document, key)
    index = _int(path, index, f"{key} index")
    if index >= len(items) or not isinstance(items[index], dict):
        raise SplatFileError(path, f"bad glTF: {key}[{index}] does not exist")
    return items[index]


def _accessor(path: Path, document: dict, buffers: list[bytes], index: Any, name: str,
              kind: str, components: tuple[int, ...]) -> np.ndarray:
    """Accessor `index` as float64 (count, width), normalised integers mapped per glTF."""
    accessor = _item(path, document, "accessors", index)
    if accessor.get("type") != kind:
        raise SplatFileError(path, f"attribute {name}: accessor type {accessor.get('type')!r}, expected {kind}")
    component = accessor.get("componentType")
    if component not in components:
        raise SplatFileError(path, f"attribute {name}: component type {component!r} is not allowed here")
    if "sparse" in accessor:
        raise SplatFileError(path, f"attribute {name}: sparse accessors are not supported")
    count, width = _int(path, accessor.get("count"), f"{name} count"), WIDTH[kind]
    dtype, size = COMPONENTS[component]
    element = width * size
    if "bufferView" not in accessor:  # all zeros by glTF's rule: never splat data
        raise SplatFileError(path, f"attribute {name}: an accessor without a bufferView (all zeros) "
                                   f"holds no Gaussians; refused")
    view = _item(path, document, "bufferViews", accessor["bufferView"])
    buffer = _int(path, view.get("buffer"), f"{name} bufferView.buffer", len(buffers) - 1)
    view_offset = _int(path, view.get("byteOffset", 0), f"{name} bufferView.byteOffset")
    view_length = _int(path, view.get("byteLength"), f"{name} bufferView.byteLength")
    stride = _int(path, view.get("byteStride", element), f"{name} byteStride", 252) or element
    offset = _int(path, accessor.get("byteOffset", 0), f"{name} accessor.byteOffset")
    needed = offset + (stride * (count - 1) + element if count else 0)
    if stride < element or needed > view_length or view_offset + view_length > len(buffers[buffer]):
        raise SplatFileError(path, f"attribute {name}: {count} elements do not fit in their buffer view "
                                   f"({needed} bytes needed, {view_length} declared)")
    start = view_offset + offset
    if stride == element:
        values = np.frombuffer(buffers[buffer], dtype, count * width, start).reshape(count, width)
    else:  # interleaved: an element every `stride` bytes (all inside `needed`, checked above)
        raw = np.frombuffer(buffers[buffer], np.uint8, needed - offset, start)
        rows = np.lib.stride_tricks.as_strided(raw, (count, element), (stride, 1), writeable=False)
        values = np.ascontiguousarray(rows).view(dtype)
    with np.errstate(invalid="ignore"):  # NaN payloads: refused by the finiteness check after
        values = values.astype(np.float64)
    if accessor.get("normalized") and component != FLOAT:
        top = {BYTE: 127.0, UBYTE: 255.0, SHORT: 32767.0, USHORT: 65535.0}[component]
        values = np.maximum(values / top, -1.0)
    return values


def _primitive_gaussians(path: Path, document: dict, buffers: list[bytes], primitive: dict) -> Gaussians:
    splat = primitive["extensions"][EXTENSION]
    if not isinstance(splat, dict):
        raise SplatFileError(path, f"bad {EXTENSION} object")
    nested = splat.get("extensions") or {}
    if SPZ_EXTENSION in nested or any("compression" in k for k in nested):
        which = SPZ_EXTENSION if SPZ_EXTENSION in nested else next(k for k in nested if "compression" in k)
        raise SplatFileError(path, f"{which} (compressed glTF splats, a draft extension) is not supported; "
                                   f"convert the file to uncompressed {EXTENSION} or to .spz first")
    if primitive.get("mode", 4) != 0:
        raise SplatFileError(path, f"a {EXTENSION} primitive must have mode POINTS (0), not {primitive.get('mode', 4)}")
    attributes = primitive.get("attributes")
    if not isinstance(attributes, dict):
        raise SplatFileError(path, "bad primitive: no attributes")
    for required in ("POSITION", f"{PREFIX}ROTATION", f"{PREFIX}SCALE", f"{PREFIX}OPACITY",
                     f"{PREFIX}SH_DEGREE_0_COEF_0"):
        if required not in attributes:
            raise SplatFileError(path, f"missing required attribute {required!r}")

    def read(name: str, kind: str, components: tuple[int, ...]) -> np.ndarray:
        return _accessor(path, document, buffers, attributes[name], name, kind, components)

    means = read("POSITION", "VEC3", (FLOAT, BYTE, UBYTE, SHORT, USHORT))
    quats = read(f"{PREFIX}ROTATION", "VEC4", (FLOAT, BYTE, SHORT))[:, [3, 0, 1, 2]]
    scales = read(f"{PREFIX}SCALE", "VEC3", (FLOAT, UBYTE, USHORT))
    opacity = read(f"{PREFIX}OPACITY", "SCALAR", (FLOAT, UBYTE, USHORT))[:, 0]
    degree = 0
    while degree < 3 and f"{PREFIX}SH_DEGREE_{degree + 1}_COEF_0" in attributes:
        degree += 1
    names = attribute_names(degree)
    missing = [n for n in names if n not in attributes]
    if missing:
        raise SplatFileError(path, f"missing {missing[0]!r}: SH degrees must be complete")
    sh = np.stack([read(n, "VEC3", (FLOAT,)) for n in names], axis=1)
    n = len(means)
    for name, values in (("ROTATION", quats), ("SCALE", scales), ("OPACITY", opacity), ("SH", sh)):
        if len(values) != n:
            raise SplatFileError(path, f"attribute {name} has {len(values)} elements, POSITION has {n}")
    if not all(np.isfinite(a).all() for a in (means, quats, scales, opacity, sh)):
        raise SplatFileError(path, "non-finite values in the splat attributes")
    if (scales < 0).any() or ((opacity < 0) | (opacity > 1)).any():
        raise SplatFileError(path, "out-of-range values: scales must be >= 0 and opacities in [0, 1]")
    tiny = np.finfo(np.float32).tiny
    log_scales = log_scales_of(np.maximum(scales, tiny))
    limit = 1.0 - np.finfo(np.float32).epsneg  # the largest float32 opacity below 1
    opacity = np.clip(opacity, tiny, limit)
    return Gaussians(means, log_scales, quats, logit(opacity), sh)


def _node_matrix(path: Path, node: dict) -> np.ndarray:
    if "matrix" in node:
        m = np.asarray(node["matrix"], np.float64)
        if m.shape != (16,) or not np.isfinite(m).all():
            raise SplatFileError(path, "bad node matrix")
        return m.reshape(4, 4).T  # column-major
    t = np.asarray(node.get("translation", [0, 0, 0]), np.float64)
    x, y, z, w = np.asarray(node.get("rotation", [0, 0, 0, 1]), np.float64)
    s = np.asarray(node.get("scale", [1, 1, 1]), np.float64)
    r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                  [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                  [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    m = np.eye(4)
    m[:3, :3] = r * s
    m[:3, 3] = t
    if not np.isfinite(m).all():
        raise SplatFileError(path, "bad node transform")
    return m


def _indices(path: Path, value: Any, name: str) -> list[int]:
    if not isinstance(value, list):
        raise SplatFileError(path, f"bad glTF: {name} is not a list")
    return [_int(path, v, name) for v in value]


def _instances(path: Path, document: dict) -> list[tuple[int, int, np.ndarray]]:
    """(node index, mesh index, global matrix) of every mesh the default scene (or else every
    root) shows. glTF nodes form trees (a node has one parent at most): each is visited once,
    and one reached twice (a shared child, a cycle, a root listed twice) is refused, so the walk
    is linear in the document whatever it declares."""
    nodes = _list(path, document, "nodes")
    scenes = _list(path, document, "scenes")
    if scenes:
        scene = _item(path, document, "scenes", document.get("scene", 0))
        roots = _indices(path, scene.get("nodes", []), "scene.nodes")
    else:
        children = {c for i, n in enumerate(nodes) if isinstance(n, dict)
                    for c in _indices(path, n.get("children", []), f"nodes[{i}].children")}
        roots = [i for i in range(len(nodes)) if i not in children]
    visited: set[int] = set()
    found, stack = [], [(r, np.eye(4), 0) for r in reversed(roots)]
    while stack:
        index, parent, depth = stack.pop()
        if depth > MAX_NODE_DEPTH:
            raise SplatFileError(path, f"bad glTF: node hierarchy deeper than {MAX_NODE_DEPTH}")
        if index in visited:
            raise SplatFileError(path, f"bad glTF: node {index} is reached twice (glTF nodes form "
                                       f"trees: one parent each, no cycles)")
        visited.add(index)
        node = _item(path, document, "nodes", index)
        with np.errstate(over="ignore", invalid="ignore"):
            matrix = parent @ _node_matrix(path, node)
        if not np.isfinite(matrix).all():
            raise SplatFileError(path, f"bad glTF: node {index}'s global transform overflows")
        if "mesh" in node:
            found.append((index, _int(path, node["mesh"], f"nodes[{index}].mesh"), matrix))
        kids = _indices(path, node.get("children", []), f"nodes[{index}].children")
        stack.extend((c, matrix, depth + 1) for c in reversed(kids))
    return found


def _splat_primitives(path: Path, document: dict, mesh_index: int) -> list[tuple[int, dict]]:
    mesh = _item(path, document, "meshes", mesh_index)
    primitives = mesh.get("primitives", [])
    if not isinstance(primitives, list):
        raise SplatFileError(path, f"bad glTF: meshes[{mesh_index}].primitives is not a list")
    return [(k, p) for k, p in enumerate(primitives)
            if isinstance(p, dict) and isinstance(p.get("extensions"), dict) and EXTENSION in p["extensions"]]


def _declared_count(path: Path, document: dict, primitive: dict) -> int:
    """POSITION's count, from the accessor alone (nothing read)."""
    attributes = primitive.get("attributes")
    if not isinstance(attributes, dict) or "POSITION" not in attributes:
        raise SplatFileError(path, "missing required attribute 'POSITION'")
    accessor = _item(path, document, "accessors", attributes["POSITION"])
    return _int(path, accessor.get("count"), "POSITION count")


def _declared_degree(primitive: dict) -> int:
    """The SH degree a primitive's attribute names declare (0..3; nothing read)."""
    attributes = primitive.get("attributes")
    degree = 0
    while degree < 3 and isinstance(attributes, dict) and \
            f"{PREFIX}SH_DEGREE_{degree + 1}_COEF_0" in attributes:
        degree += 1
    return degree


def load(path: str | os.PathLike) -> Gaussians:
    """Read every KHR_gaussian_splatting primitive of a `.glb` / `.gltf` into one `Gaussians`."""
    path = Path(path)
    with malformed(path, "glTF"):
        return _load(path)


def _load(path: Path) -> Gaussians:
    data = read_regular(path, path, "file")
    if data[:4] == b"glTF":
        document, binary = _split_glb(path, data)
    else:
        if len(data) > MAX_JSON_BYTES:
            raise SplatFileError(path, f"glTF JSON larger than {MAX_JSON_BYTES} bytes")
        document, binary = _parse_json(path, data), None
    version = str((document.get("asset") or {}).get("version", ""))
    if not version.startswith("2."):
        raise SplatFileError(path, f"unsupported glTF version {version!r}: expected 2.x")
    unknown = [e for e in _list(path, document, "extensionsRequired") if e != EXTENSION]
    if unknown:
        raise SplatFileError(path, f"requires unsupported extension {unknown[0]}"
                                   + (" (a draft; not supported)" if unknown[0] == SPZ_EXTENSION else ""))
    instances = _instances(path, document)
    # Every instance's count, in total, against the limit before any buffer is read.
    shown = [(node, mesh, matrix, _splat_primitives(path, document, mesh)) for node, mesh, matrix in instances]
    total = sum(_declared_count(path, document, p) for *_, prims in shown for _, p in prims)
    check_gaussian_count(path, total, "Gaussians in the scene's instances")
    if not any(prims for *_, prims in shown):
        raise SplatFileError(path, f"no {EXTENSION} primitive in the scene: not a Gaussian splat glTF")
    degree = max(_declared_degree(p) for *_, prims in shown for _, p in prims)
    buffers, external = _buffers(path, document, binary)
    # Instances multiply a primitive's bytes: 166 nodes showing one 60k-Gaussian primitive of a
    # 724 KB .glb asked for 2.5 GB (issue 33). Refused here, before anything is decoded.
    check_expansion(path, total, degree, len(data) + external, " in the scene's instances")
    decoded: dict[tuple[int, int], Gaussians] = {}  # a mesh shown by several nodes is read once
    out = Assembly(total, degree)  # each instance written in place: no copies to concatenate
    for node, mesh_index, matrix, primitives in shown:
        for k, primitive in primitives:
            if (mesh_index, k) not in decoded:
                decoded[(mesh_index, k)] = _primitive_gaussians(path, document, buffers, primitive)
            g = decoded[(mesh_index, k)]
            if not np.allclose(matrix, np.eye(4), rtol=0, atol=1e-12):
                try:
                    with np.errstate(over="ignore", invalid="ignore"):
                        g = transform_gaussians(g, matrix)
                except ValueError as e:
                    raise SplatFileError(path, f"bad node transform: {e}") from None
                bad = g.non_finite()
                if bad is not None:
                    raise SplatFileError(path, f"node {node}'s transform makes {bad} non-finite "
                                               f"(values beyond float32)")
            out.put(rdf_to_rub(g))
    return out.gaussians()
