"""PlayCanvas streamed SOG (a level-of-detail set): read one level of `lod-meta.json`.

Layout (developer.playcanvas.com, "The Streamed SOG Format", version 1, and the unversioned files
written before it): `lod-meta.json` names chunk SOGs (`filenames`, paths of folder-form
`meta.json` relative to it) and holds a binary spatial tree whose leaves map each LOD level
("0" is the finest) to a run `{file, offset, count}` of Gaussians inside one chunk. A level is
the union of its leaves' runs; an optional `environment` SOG (far background) belongs to every
level.

`load(path, level=0)` reads every chunk of one level and returns the runs in tree order (each
chunk is read once, whatever number of runs it holds, and let go before the next is read).

Bounds, all before anything is decoded: chunk names are judged by `contained.contained_file`
(inside the set's folder, links followed, regular files); the tree is walked once, at most
`MAX_TREE_NODES` nodes; the runs of the level must lie inside their chunk and not overlap, and
together, like the chunks read for them, stay within `formats_common.limits.MAX_GAUSSIANS`.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from ..gaussians import Gaussians
from ..formats_common.contained import contained_file, is_contained_name, read_regular, unrepresentable
from ..formats_common.errors import SplatFileError
from ..formats_common.json_file import malformed, parse_object
from ..formats_common.limits import check_gaussian_count
from .sog import MAX_COUNT, chunk_count, load_chunk

__all__ = ["load", "levels", "LOD_META"]

LOD_META = "lod-meta.json"
MAX_INDEX_BYTES = 64 << 20
MAX_TREE_NODES = 1 << 20
READ_VERSION = 1


def _read_index(path: Path) -> dict[str, Any]:
    text = read_regular(path, path, "lod-meta.json", MAX_INDEX_BYTES)
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
    environment = index.get("environment")
    if environment is not None and not isinstance(environment, str):
        raise SplatFileError(path, "bad 'environment': expected a path")
    for name in names + ([environment] if environment is not None else []):
        if not is_contained_name(name):
            problem = unrepresentable(name) or "must be relative, inside the set's folder"
            raise SplatFileError(path, f"bad chunk path {name[:200]!r}: {problem}")
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
        lods = node.get("lods") or {}
        if not isinstance(lods, dict):
            raise SplatFileError(path, "bad 'tree': 'lods' must be an object")
        run = lods.get(str(level))
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
    with malformed(path, "lod-meta.json"):
        return _load(path, level, environment)


def _check_runs(path: Path, runs: list[tuple[Path, int, int]], counts: dict[Path, int]) -> None:
    """Every run inside its chunk, no two overlapping (a tree repeating a leaf, or naming one
    chunk under several file indices, would otherwise copy the same Gaussians again and again)."""
    for chunk, offset, count in runs:
        if offset + count > counts[chunk]:
            raise SplatFileError(path, f"run of {count} at {offset} is beyond chunk "
                                       f"{chunk.parent.name!r} of {counts[chunk]} Gaussians")
    ordered = sorted(runs)
    for (chunk, offset, count), (next_chunk, next_offset, _) in zip(ordered, ordered[1:]):
        if chunk == next_chunk and next_offset < offset + count:
            raise SplatFileError(path, f"runs at {offset} and {next_offset} of chunk {chunk.parent.name!r} "
                                       f"overlap: a level holds each Gaussian once")


def _load(path: Path, level: int, environment: bool) -> Gaussians:
    index = _read_index(path)
    if not 0 <= level < index["lodLevels"]:
        raise SplatFileError(path, f"no LOD level {level}: the set has levels 0..{index['lodLevels'] - 1}")
    names = index["filenames"]
    runs = [run for run in _runs(path, index, level) if run[2] > 0]  # empty runs read nothing
    check_gaussian_count(path, sum(count for _, _, count in runs), f"Gaussians at level {level}")
    # Chunks by the file they are (several indices may name one): each read once.
    judged: dict[str, Path] = {}  # by name: a name repeated under many indices is judged once
    chunks = {}
    for file in {file for file, _, _ in runs}:
        if names[file] not in judged:
            judged[names[file]] = contained_file(path.parent, names[file], path, f"chunk {file}").resolve()
        chunks[file] = judged[names[file]]
    runs_in = [(chunks[file], offset, count) for file, offset, count in runs]
    env = index.get("environment") if environment else None
    env_file = contained_file(path.parent, env, path, "environment") if env is not None else None
    counts = {chunk: chunk_count(chunk) for chunk in set(chunks.values())}
    _check_runs(path, runs_in, counts)
    total = sum(count for _, _, count in runs) + (chunk_count(env_file) if env_file else 0)
    check_gaussian_count(path, total, f"Gaussians at level {level} with the environment")
    for chunk, count in counts.items():
        check_gaussian_count(chunk, count)
    by_chunk: dict[Path, list[int]] = {}
    for i, (chunk, _, _) in enumerate(runs_in):
        by_chunk.setdefault(chunk, []).append(i)
    parts: list[Gaussians | None] = [None] * len(runs_in)
    for chunk_path, indices in by_chunk.items():  # one chunk in memory at a time
        chunk = load_chunk(chunk_path)
        if len(chunk) != counts[chunk_path]:
            raise SplatFileError(path, f"chunk {chunk_path.parent.name!r} changed while it was read")
        for i in indices:
            _, offset, count = runs_in[i]
            parts[i] = chunk.subset(slice(offset, offset + count))
        del chunk
    parts = [p for p in parts if p is not None]
    if env_file is not None:
        parts.append(load_chunk(env_file))
    if not parts:
        return Gaussians.empty()
    degree = max(p.degree for p in parts)
    parts = [p if p.degree == degree else p.with_degree(degree) for p in parts]
    return Gaussians(*(np.concatenate([getattr(p, name) for p in parts])
                       for name in ("means", "log_scales", "quats", "opacity_logits", "sh")))
