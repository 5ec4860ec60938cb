"""The COLMAP reader's one exception type, and the one place pycolmap is imported."""

from __future__ import annotations

from types import ModuleType


class ColmapError(ValueError):
    """Bad or unusable COLMAP input; the message names the file or folder and the problem."""


def import_pycolmap() -> ModuleType:
    """pycolmap, or a ColmapError saying how to get it."""
    try:
        import pycolmap
    except ImportError as error:
        raise ColmapError(
            "reading COLMAP models needs pycolmap 4.x, which this Python cannot import "
            f"({error}); install it (pip install pycolmap) or bundle its wheel") from error
    return pycolmap
