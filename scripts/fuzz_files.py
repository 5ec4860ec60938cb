"""Seeds and format-aware mutations for the readers of files that hold other files or JSON:
SOG folders and `.sog` bundles, streamed SOG (LOD) sets, glTF (`.gltf` with an external buffer
or a data URI, `.glb`) and sequences (a folder of numbered splat files). Used by scripts/fuzz.py.

A seed is {relative path: bytes}; three markers stand for what bytes cannot (scripts/fuzz.py
makes them): LINK + target (a symbolic link: "../outside/secret.bin", "/dev/zero", ...), FIFO
(a named pipe) and FOLDER. Every mutant's folder has a sibling `outside/` holding a valid
secret buffer, splat and SOG: a reader that opens anything there has left the user's folder.

Mutations, by what the format holds:
- JSON (meta.json, lod-meta.json, the glTF document): a field's value replaced by another type,
  an interesting number, a huge or negative count, a non-finite number, a long string, a deep
  nesting; keys deleted; list items repeated (counts); path fields (uris, file names) replaced
  by hostile paths in POSIX and Windows forms, links and FIFOs.
- glTF node graphs: children that share nodes (DAGs), cycles, roots listed many times, scales
  that overflow float32, accessors with no buffer view or huge counts.
- LOD trees: a leaf repeated thousands of times, deep chains, runs beyond or across chunks.
- zip members (.sog): renamed (".", "..", long, absolute, Windows forms), recompressed, dropped,
  duplicated, replaced by a deflated bomb, their bytes mutated.
- WebP images: bytes corrupted, the VP8L header's width/height changed, replaced by a valid
  image of another size.
- sequences: many frames (hundreds), duplicate numbers, frames of another format, links out,
  FIFOs and folders named like frames, one frame corrupted.
"""

from __future__ import annotations

import copy
import io
import json
import random
import struct
import tempfile
import warnings
import zipfile
from pathlib import Path
from typing import Any, Callable

import numpy as np

LINK = b"\0fuzz-link\0"
FIFO = b"\0fuzz-fifo\0"
FOLDER = b"\0fuzz-folder\0"

HOSTILE_PATHS = ["../outside/secret.bin", "../outside/meta.json", "../outside/secret.ply", "/etc/passwd",
                 "/dev/zero", "C:/Windows/win.ini", "C:\\Windows\\win.ini", "C:secret.bin",
                 "..\\..\\outside\\secret.bin", "..\\outside\\secret.bin", "\\\\host\\share\\x.bin",
                 "//host/share/x.bin", "\\Windows\\x.bin", "%2e%2e/outside/secret.bin", "CON", "nul.bin",
                 "a/../../outside/secret.bin", ".", "..", "", "./", "x" * 5000, "a:b.bin",
                 "file:///etc/passwd", "http://example.com/x.bin", "fifo", "link_out", "link_dev",
                 "folder", "missing.bin", "a\0b"]
DEEP = "\0fuzz-deep"  # replaced by a nesting too deep for json.dumps, in the text
HOSTILE_VALUES: list[Any] = [None, True, False, -1, 0, 1, 2**31, 2**32 + 1, 2**53, 2**63, -2**63, 10**30,
                             1e308, -1e308, 3.5e38, 1e-320, float("nan"), float("inf"), "x", "", [], {},
                             [0] * 3, [1e39, 1e39, 1e39], 12_000_000, 10_000_001, 1_000_000_000]
SPECIAL_FILES = {"fifo": FIFO, "link_out": LINK + b"../outside/secret.bin", "link_dev": LINK + b"/dev/zero",
                 "folder": FOLDER}


def _saved_folder(write: Callable[[Path], None]) -> dict[str, bytes]:
    with tempfile.TemporaryDirectory() as tmp:
        write(Path(tmp))
        return {str(p.relative_to(tmp)): p.read_bytes() for p in sorted(Path(tmp).rglob("*")) if p.is_file()}


def outside_files(g) -> dict[str, bytes]:
    """What lies beside the user's folder: valid data a reader must never pick up."""
    from addon.core.formats import ply, sog
    files = {"secret.bin": bytes(range(256)) * 64}
    files.update(_saved_folder(lambda d: ply.save(g, d / "secret.ply")))
    files.update(_saved_folder(lambda d: sog.save(g, d / "meta.json")))
    return files


def spare_images() -> list[bytes]:
    """Valid lossless WebP images of other sizes, to swap in for a SOG's own."""
    from addon.core.formats_common import webp
    images = []
    with tempfile.TemporaryDirectory() as tmp:
        for height, width in ((1, 1), (4, 4), (64, 64), (1, 4096), (300, 300)):
            path = Path(tmp) / "i.webp"
            webp.write_rgba(path, np.full((height, width, 4), 7, np.uint8))
            images.append(path.read_bytes())
    return images


def seeds(g, g_sh0, make_seed: Callable[[str, str, dict[str, bytes]], Any]) -> list:
    """One small seed per reader of this module."""
    from addon.core.formats import gltf, ply, sog, splat, spz
    out = []
    folder = _saved_folder(lambda d: sog.save(g, d / "meta.json"))
    out.append(make_seed("sog_folder", "meta.json", folder))
    bundle = _saved_folder(lambda d: sog.save(g, d / "a.sog"))
    out.append(make_seed("sog_bundle", "a.sog", bundle))

    def lod(d: Path) -> None:
        half = len(g) // 2
        sog.save(g.subset(slice(0, half)), d / "chunk0" / "meta.json")
        sog.save(g.subset(slice(half, None)), d / "chunk1" / "meta.json")
        sog.save(g_sh0, d / "env" / "meta.json")
        leaf = lambda f, o, c: {"lods": {"0": {"file": f, "offset": o, "count": c},  # noqa: E731
                                         "1": {"file": f, "offset": o, "count": max(1, c // 2)}}}
        tree = {"children": [leaf(0, 0, half), {"children": [leaf(1, 0, 3), leaf(1, 3, len(g) - half - 3)]}]}
        (d / "lod-meta.json").write_text(json.dumps({
            "version": 1, "lodLevels": 2, "filenames": ["chunk0/meta.json", "chunk1/meta.json"],
            "environment": "env/meta.json", "tree": tree}))
    out.append(make_seed("sog_lod", "lod-meta.json", _saved_folder(lod)))

    glb = _saved_folder(lambda d: gltf.save(g, d / "a.glb"))
    out.append(make_seed("glb", "a.glb", glb))
    embedded = _saved_folder(lambda d: gltf.save(g, d / "a.gltf"))
    out.append(make_seed("gltf", "a.gltf", embedded))
    # An external buffer and two nodes showing meshes through a small tree (uris and graphs).
    document = json.loads(embedded["a.gltf"])
    data = document["buffers"][0]["uri"].split(",", 1)[1]
    import base64
    document["buffers"][0]["uri"] = "a.bin"
    document["nodes"] = [{"children": [1, 2]}, {"mesh": 0, "translation": [1, 0, 0]},
                         {"mesh": 0, "scale": [2, 2, 2]}]
    document["scenes"] = [{"nodes": [0]}]
    out.append(make_seed("gltf_external", "a.gltf", {"a.gltf": json.dumps(document).encode(),
                                                     "a.bin": base64.b64decode(data)}))

    def frames(d: Path) -> None:
        (d / "seq").mkdir()
        ply.save(g, d / "seq" / "walk_0001.ply")
        splat.save(g_sh0, d / "seq" / "walk_0002.splat")
        spz.save(g, d / "seq" / "walk_0004.spz", 3)
    out.append(make_seed("sequence", "seq", _saved_folder(frames)))
    return out


# -- JSON ------------------------------------------------------------------------------------------

def _slots(document: Any) -> list[tuple[Any, Any]]:
    """(container, key) of every value in a JSON document, iteratively."""
    slots, stack = [], [document]
    while stack:
        node = stack.pop()
        items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
        for key, value in items:
            slots.append((node, key))
            if isinstance(value, (dict, list)) and len(slots) < 20000:
                stack.append(value)
    return slots


def _deep(depth: int) -> Any:
    value: Any = 0
    for _ in range(depth):
        value = [value]
    return value


def _mutate_json_value(document: Any, rnd: random.Random) -> None:
    slots = _slots(document)
    if not slots:
        return
    container, key = rnd.choice(slots)
    value = container[key]
    choice = rnd.randrange(8)
    if choice == 0:
        container[key] = rnd.choice(HOSTILE_VALUES)
    elif choice == 1 and isinstance(value, (int, float)) and not isinstance(value, bool):
        container[key] = rnd.choice([value * 1000, -value, value + 1, value - 1, 2 * value, 10**9, 2**31 - 1])
    elif choice == 2 and isinstance(value, list) and value:
        k = rnd.randrange(len(value))
        container[key] = value + [copy.deepcopy(value[k])] * rnd.choice((1, 2, 100, 5000))
    elif choice == 3 and isinstance(container, dict):
        del container[key]
    elif choice == 4:
        container[key] = _deep(rnd.choice((30, 250, 900))) if rnd.random() < 0.5 else DEEP
    elif choice == 5 and isinstance(value, str):
        container[key] = rnd.choice(HOSTILE_PATHS)
    elif choice == 6:
        container[key] = [value] if rnd.random() < 0.5 else {"x": value}
    else:
        container[key] = rnd.choice((str(value)[:40], "x" * rnd.choice((1, 300, 100000))))


def _path_fields(document: Any) -> list[tuple[Any, Any]]:
    return [(c, k) for c, k in _slots(document)
            if isinstance(c[k], str) and ("." in c[k] or "/" in c[k]) and not c[k].startswith("data:")
            or k in ("uri", "files", "filenames", "environment")]


def mutate_json(data: bytes, rnd: random.Random, graph: Callable[[Any, random.Random], None] | None = None) -> bytes:
    try:
        document = json.loads(data)
    except (ValueError, UnicodeDecodeError, RecursionError):
        return _mutate_text(data, rnd)
    for _ in range(rnd.choice((1, 1, 2, 3))):
        kind = rnd.randrange(10)
        if kind < 3 and graph is not None:
            graph(document, rnd)
        elif kind < 5:
            paths = _path_fields(document)
            if paths:
                container, key = rnd.choice(paths)
                if isinstance(container[key], list) and container[key]:
                    container[key][rnd.randrange(len(container[key]))] = rnd.choice(HOSTILE_PATHS)
                else:
                    container[key] = rnd.choice(HOSTILE_PATHS)
        else:
            _mutate_json_value(document, rnd)
    try:
        text = json.dumps(document, allow_nan=rnd.random() < 0.8)
    except (ValueError, RecursionError):
        return data
    depth = rnd.choice((1000, 20000, 200000))
    text = text.replace(json.dumps(DEEP), "[" * depth + "0" + "]" * depth)
    return text.encode("utf-8", "surrogatepass")


def _mutate_text(data: bytes, rnd: random.Random) -> bytes:
    from scripts.fuzz import _mutate_bytes
    return _mutate_bytes(data, rnd)


# -- glTF node graphs and LOD trees ----------------------------------------------------------------

def gltf_graph(document: dict, rnd: random.Random) -> None:
    nodes = document.setdefault("nodes", [{}])
    if not isinstance(nodes, list) or not nodes:
        return
    n = len(nodes)
    kind = rnd.randrange(7)
    if kind == 0:  # a DAG: every node lists all later ones (paths double per level)
        extra = [{"children": list(range(i + 1, n + 40))} for i in range(n, n + 40)]
        nodes.extend(extra)
        for i in range(n):
            if isinstance(nodes[i], dict):
                nodes[i]["children"] = list(range(n, n + 40))
    elif kind == 1:  # a cycle
        if isinstance(nodes[-1], dict):
            nodes[-1]["children"] = [0]
    elif kind == 2:  # one root listed many times
        document["scenes"] = [{"nodes": [0] * rnd.choice((2, 1000, 100000))}]
    elif kind == 3:  # transforms that overflow
        target = nodes[rnd.randrange(n)]
        if isinstance(target, dict):
            target.pop("matrix", None)
            target["scale"] = rnd.choice(([3e38, 3e38, 3e38], [1e20, 1e20, 1e20], [0, 0, 0], [float("nan")] * 3))
    elif kind == 4:  # accessors without buffer views, or declaring huge counts
        for accessor in document.get("accessors", []) if isinstance(document.get("accessors"), list) else []:
            if isinstance(accessor, dict):
                if rnd.random() < 0.5:
                    accessor.pop("bufferView", None)
                accessor["count"] = rnd.choice((10**9, 2**31, accessor.get("count", 1)))
    elif kind == 5:  # many instances of the mesh
        nodes.extend({"mesh": 0} for _ in range(rnd.choice((10, 1000, 20000))))
        document["scenes"] = [{"nodes": list(range(len(nodes)))}]
        document["scene"] = 0
    else:  # a deep chain
        start = len(nodes)
        nodes.extend({"children": [start + i + 1]} for i in range(rnd.choice((50, 70, 2000))))
        nodes.append({"mesh": 0})
        document["scenes"] = [{"nodes": [start]}]


def lod_tree(document: dict, rnd: random.Random) -> None:
    tree = document.get("tree")
    kind = rnd.randrange(4)
    if kind == 0:  # one leaf repeated many times
        leaf = tree
        while isinstance(leaf, dict) and isinstance(leaf.get("children"), list) and leaf["children"]:
            leaf = leaf["children"][0]
        document["tree"] = {"children": [leaf] * rnd.choice((2, 1000, 50000))}
    elif kind == 1:  # a deep chain
        node = tree
        for _ in range(rnd.choice((100, 3000))):
            node = {"children": [node]}
        document["tree"] = node
    elif kind == 2:  # runs across or beyond chunks
        for container, key in _slots(document):
            if key in ("offset", "count", "file") and rnd.random() < 0.3:
                container[key] = rnd.choice((0, 1, 5, 6, 10**6, 2**27, -1))
    else:
        document["lodLevels"] = rnd.choice((0, 1, 2, 64, 65, 10**9, "2", None))


# -- zip members and WebP images -------------------------------------------------------------------

def _zip(members: list[tuple[str, bytes, int]]) -> bytes:
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as archive:
        for name, data, compression in members:
            info = zipfile.ZipInfo(name)
            info.compress_type = compression
            archive.writestr(info, data)
    return out.getvalue()


def mutate_webp(data: bytes, rnd: random.Random, spares: list[bytes]) -> bytes:
    kind = rnd.randrange(4)
    if kind == 0 and spares:
        return rnd.choice(spares)
    if kind == 1 and len(data) > 25 and data[12:16] == b"VP8L":
        bits = struct.unpack_from("<I", data, 21)[0]
        width, height = rnd.randrange(1 << 14), rnd.randrange(1 << 14)
        bits = (bits & ~((1 << 28) - 1)) | width | (height << 14)
        return data[:21] + struct.pack("<I", bits) + data[25:]
    if kind == 2 and len(data) > 12:  # the RIFF size
        return data[:4] + struct.pack("<I", rnd.choice((0, 1, len(data), 2**31, 2**32 - 1))) + data[8:]
    return _mutate_text(data, rnd)


def mutate_zip(data: bytes, rnd: random.Random, spares: list[bytes]) -> bytes:
    warnings.simplefilter("ignore", UserWarning)  # duplicate member names are a mutation
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            members = [(i.filename, archive.read(i), i.compress_type) for i in archive.infolist()]
    except Exception:  # noqa: BLE001 - already broken: mutate the bytes
        return _mutate_text(data, rnd)
    if not members or rnd.random() < 0.15:
        return _mutate_text(data, rnd)  # sizes and offsets in the local and central headers
    k = rnd.randrange(len(members))
    name, content, compression = members[k]
    kind = rnd.randrange(8)
    if kind == 0:
        hostile = [".", "..", "/", "a/", "x" * 300, "x" * 5000, "../meta.json", "/etc/passwd",
                   "C:/meta.json", "..\\x.webp", "\\\\h\\s\\x", "CON", "meta.json"]
        members[k] = (rnd.choice(hostile), content, compression)
    elif kind == 1:
        members[k] = (name, content, zipfile.ZIP_DEFLATED if compression == zipfile.ZIP_STORED else zipfile.ZIP_STORED)
    elif kind == 2:
        del members[k]
    elif kind == 3:
        members.append(members[k])
    elif kind == 4:  # a bomb: zeros deflated a thousand times
        members[k] = (name, bytes(rnd.choice((1 << 20, 16 << 20, 64 << 20))), zipfile.ZIP_DEFLATED)
    elif name.endswith(".json"):
        members[k] = (name, mutate_json(content, rnd), compression)
    else:
        members[k] = (name, mutate_webp(content, rnd, spares), compression)
    try:
        return _zip(members)
    except (ValueError, OSError):
        return data


# -- sequences -------------------------------------------------------------------------------------

def mutate_sequence(files: dict[str, bytes], rnd: random.Random) -> dict[str, bytes]:
    frames = sorted(n for n in files if n.startswith("seq/"))
    kind = rnd.randrange(7)
    if kind == 0 and frames:  # many frames
        source = files[rnd.choice(frames)]
        suffix = Path(rnd.choice(frames)).suffix
        for i in range(rnd.choice((50, 300, 1000))):
            files[f"seq/walk_{1000 + i:05d}{suffix}"] = source
    elif kind == 1 and frames:  # the same number twice
        name = rnd.choice(frames)
        files[name.replace("_000", "_")] = files[name]
    elif kind == 2:  # a link, FIFO or folder named like a frame
        files[f"seq/walk_{rnd.randrange(9000):04d}.ply"] = rnd.choice(
            [LINK + b"../outside/secret.ply", LINK + b"/dev/zero", LINK + b"/etc/passwd", FIFO, FOLDER,
             LINK + b"walk_0001.ply", LINK + b"loop.ply"])
        files["seq/loop.ply"] = LINK + b"loop.ply"
    elif kind == 3 and frames:  # one frame corrupted
        name = rnd.choice(frames)
        files[name] = _mutate_text(files[name], rnd)
    elif kind == 4 and frames:  # a frame in another format's clothes
        name = rnd.choice(frames)
        files[str(Path(name).with_suffix(rnd.choice((".spz", ".splat", ".ply", ".glb", ".sog"))))] = files.pop(name)
    elif kind == 5:  # odd numbers
        if frames:
            files[f"seq/walk_{'9' * rnd.choice((20, 200))}.ply"] = files[frames[0]]
    else:
        files[f"seq/walk_{rnd.randrange(10):04d}.ply"] = b""
    return files


def mutate(reader: str, files: dict[str, bytes], name: str, rnd: random.Random,
           spares: list[bytes]) -> dict[str, bytes]:
    """One mutant of a seed of this module's readers (a new dict; the seed is not changed)."""
    files = dict(files)
    if reader == "sequence":
        return mutate_sequence(files, rnd)
    if rnd.random() < 0.08:  # a hostile special file the JSON may name
        special = rnd.choice(sorted(SPECIAL_FILES))
        files[special] = SPECIAL_FILES[special]
    target = rnd.choice(sorted(n for n in files if not files[n].startswith(b"\0fuzz")))
    data = files[target]
    graph = gltf_graph if reader.startswith("gltf") or reader == "glb" else lod_tree if reader == "sog_lod" else None
    if target.endswith(".webp"):
        files[target] = mutate_webp(data, rnd, spares)
    elif target.endswith(".sog"):
        files[target] = mutate_zip(data, rnd, spares)
    elif target.endswith(".json") or target.endswith(".gltf"):
        files[target] = mutate_json(data, rnd, graph) if rnd.random() < 0.8 else _mutate_text(data, rnd)
    elif target.endswith(".glb") and len(data) > 20 and rnd.random() < 0.7:
        size = struct.unpack_from("<I", data, 12)[0]
        text = mutate_json(data[20:20 + size], rnd, graph)
        text += b" " * ((-len(text)) % 4)
        rest = data[20 + size:]
        files[target] = struct.pack("<4sII", b"glTF", 2, 20 + len(text) + len(rest)) + \
            struct.pack("<II", len(text), 0x4E4F534A) + text + rest
    else:
        files[target] = _mutate_text(data, rnd)
    return files


def write(folder: Path, files: dict[str, bytes]) -> None:
    """Make the mutant's files (links, FIFOs and folders from their markers)."""
    import os
    for name, data in files.items():
        path = folder / name
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            if data.startswith(LINK):
                os.symlink(data[len(LINK):].decode(), path)
            elif data == FIFO:
                os.mkfifo(path)
            elif data == FOLDER:
                path.mkdir(exist_ok=True)
            else:
                path.write_bytes(data)
        except (OSError, ValueError):
            pass  # a name the file system refuses: the mutant goes on without it
