"""PlayCanvas streamed SOG (a level-of-detail set): read one level of `lod-meta.json`.

Layout (developer.playcanvas.com, "The Streamed SOG Format", version 1, and the unversioned files
written before it): `lod-meta.json` names chunk SOGs (`filenames`, paths of folder-form
`meta.json` relative to it) and holds a binary spatial tree whose leaves map each LOD level
("0" is the finest) to a run `{file, offset, count}` of Gaussians inside one chunk. A level is
the union of its leaves' runs; an optional `environment` SOG (far background) belongs to every
level.

`load(path, level=0)` reads every chunk of one level and returns the runs in tree order (each
chunk is read once, whatever number of runs it holds).
"""

from __future__ import annotations

import os
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np

from ..gaussians import Gaussians
from .errors import SplatFileError
from .json_file import parse_object
from .sog import MAX_COUNT, load_chunk

__all__ = ["load", "levels", "LOD_META"]

LOD_META = "lod-meta.json"
MAX_INDEX_BYTES = 64 << 20
MAX_TREE_NODES = 1 << 20
READ_VERSION = 1


def _read_index(path: Path) -> dict[str, Any]:
    try:
        if path.stat().st_size > MAX_INDEX_BYTES:
            raise SplatFileError(path, f"lod-meta.json is larger than {MAX_INDEX_BYTES} bytes")
        text = path.read_bytes()
    except OSError as e:
        raise SplatFileError(path, f"cannot read file: {e.strerror or e}") from None
    index = parse_object(path, text, "lod-meta.json")
    version = index.get("version", READ_VERSION)  # files before version 1 have none
    if not isinstance(version, int) or version > READ_VERSION:
        raise SplatFileError(path, f"unsupported streamed SOG version {version!r}: expected {READ_VERSION}")
    count = index.get("lodLevels")
    if isinstance(count, bool) or not isinstance(count, int) or not 1 <= count <= 64:
        raise SplatFileError(path, f"bad lodLevels {count!r}: expected an integer in [1, 64]")
    names = index.get("filenames")
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise SplatFileError(path, "bad 'filenames': expected a list of paths")
    for name in names + ([index["environment"]] if isinstance(index.get("environment"), str) else []):
        pure = PurePosixPath(name)
        if pure.is_absolute() or ".." in pure.parts or "\\" in name:
            raise SplatFileError(path, f"bad chunk path {name!r}: must be relative, inside the set's folder")
    return index


def levels(path: str | os.PathLike) -> int:
    """How many LOD levels the set has (level 0 is the finest)."""
    return _read_index(Path(path))["lodLevels"]


def _runs(path: Path, index: dict[str, Any], level: int) -> list[tuple[int, int, int]]:
    """(file, offset, count) of every leaf holding `level`, in tree order (depth first)."""
    runs, stack, visited = [], [index.get("tree")], 0
    while stack:
        node = stack.pop()
        visited += 1
        if visited > MAX_TREE_NODES or not isinstance(node, dict):
            raise SplatFileError(path, "bad 'tree': expected nested objects of at most "
                                       f"{MAX_TREE_NODES} nodes")
        children = node.get("children")
        if children is not None:
            if not isinstance(children, list):
                raise SplatFileError(path, "bad 'tree': 'children' must be a list")
            stack.extend(reversed(children))
            continue
        run = (node.get("lods") or {}).get(str(level))
        if run is None:
            continue
        values = [run.get(k) if isinstance(run, dict) else None for k in ("file", "offset", "count")]
        if not all(isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= MAX_COUNT for v in values) \
                or values[0] >= len(index["filenames"]):
            raise SplatFileError(path, f"bad run {run!r} at level {level}: expected file < "
                                       f"{len(index['filenames'])} and non-negative offset and count")
        runs.append(tuple(values))
    return runs


def load(path: str | os.PathLike, level: int = 0, *, environment: bool = True) -> Gaussians:
    """All chunks of one LOD `level` (0, the finest, by default), plus the environment splats."""
    path = Path(path)
    index = _read_index(path)
    if not 0 <= level < index["lodLevels"]:
        raise SplatFileError(path, f"no LOD level {level}: the set has levels 0..{index['lodLevels'] - 1}")
    runs = _runs(path, index, level)
    chunks: dict[int, Gaussians] = {}
    parts = []
    for file, offset, count in runs:
        if file not in chunks:
            chunks[file] = load_chunk(path.parent / index["filenames"][file], path)
        chunk = chunks[file]
        if offset + count > len(chunk):
            raise SplatFileError(path, f"run of {count} at {offset} is beyond chunk "
                                       f"{index['filenames'][file]!r} of {len(chunk)} Gaussians")
        parts.append(chunk.subset(slice(offset, offset + count)))
    if environment and isinstance(index.get("environment"), str):
        parts.append(load_chunk(path.parent / index["environment"], path))
    if not parts:
        return Gaussians.empty()
    degree = max(p.degree for p in parts)
    parts = [p if p.degree == degree else p.with_degree(degree) for p in parts]
    return Gaussians(*(np.concatenate([getattr(p, name) for p in parts])
                       for name in ("means", "log_scales", "quats", "opacity_logits", "sh")))
