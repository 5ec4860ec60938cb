"""Load and save Gaussians, choosing the file format from the file name.

`load(path) -> Gaussians` and `save(gaussians, path)` are the only entry points scripts need;
each format lives in its own module under `formats/` and converts to the design's in-memory
layout at the file boundary. Every reader raises `SplatFileError` (a `ValueError`) naming the file
and the problem; every writer writes a temporary file and renames it over the target.
"""

from __future__ import annotations

import os
from pathlib import Path
from types import ModuleType

from .formats.errors import SplatFileError
from .gaussians import Gaussians

__all__ = ["SplatFileError", "load", "save", "SUFFIXES"]

SUFFIXES = (".ply", ".splat", ".spz")


def _suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise SplatFileError(path, f"unknown splat format {suffix or '(no extension)'!r}; "
                                   f"expected one of {', '.join(SUFFIXES)}")
    return suffix


def _module(suffix: str) -> ModuleType:
    # Imported on use so one format's optional needs never stop the others from loading.
    if suffix == ".splat":
        from .formats import splat
        return splat
    if suffix == ".spz":
        from .formats import spz
        return spz
    from .formats import ply
    return ply


def load(path: str | os.PathLike) -> Gaussians:
    """Read a splat file into `Gaussians`; the format follows from the extension."""
    path = Path(path)
    return _module(_suffix(path)).load(path)


def save(gaussians: Gaussians, path: str | os.PathLike) -> None:
    """Write `gaussians` to `path` atomically; the format follows from the extension."""
    path = Path(path)
    _module(_suffix(path)).save(gaussians, path)
