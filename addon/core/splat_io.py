"""Load and save Gaussians, choosing the file format from the file name.

`load(path) -> Gaussians` and `save(gaussians, path)` are the only entry points scripts need;
the formats, what each can hold and which module reads and writes it are one table,
`formats.registry.FORMATS` (also what the import/export operators use). Every reader raises
`SplatFileError` (a `ValueError`) naming the file and the problem; every writer writes a
temporary file and renames it over the target.
"""

from __future__ import annotations

import os

from .formats import registry
from .formats_common.errors import SplatFileError
from .gaussians import Gaussians

__all__ = ["SplatFileError", "load", "save", "SUFFIXES"]

# Name endings that load (".ply", ".sog", "meta.json", ...): kept for callers that filter by it.
SUFFIXES = registry.import_patterns()


def load(path: str | os.PathLike) -> Gaussians:
    """Read a splat file into `Gaussians`; the format follows from the name."""
    return registry.read(path)[0]


def save(gaussians: Gaussians, path: str | os.PathLike, *, antialiased: bool = False) -> list[str]:
    """Write `gaussians` to `path` atomically; the format follows from the name. Returns
    warnings about what the format could not hold (SH bands beyond its limit are dropped)."""
    return registry.write(gaussians, path, antialiased=antialiased)
