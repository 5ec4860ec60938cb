"""The COLMAP reader's one exception type, and the one place pycolmap is imported."""

from __future__ import annotations

import sys
from types import ModuleType


class ColmapError(ValueError):
    """Bad or unusable COLMAP input; the message names the file or folder and the problem."""


def _shared_gflags_loaded() -> bool:
    """Whether this process has a shared libgflags loaded (Linux distributions' Blender builds
    link the system's glog/gflags). pycolmap's own glog then registers its flags a second time
    in that library, and gflags ends the process: Debian's Blender 5.2 quits on
    `import pycolmap`."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as maps:
            return "/libgflags" in maps.read()
    except OSError:
        return False


def pycolmap_refusal() -> str | None:
    """Why pycolmap must not be imported in this process (None: it may be tried)."""
    if "pycolmap" not in sys.modules and _shared_gflags_loaded():
        return ("it cannot be loaded in this Blender, which uses the system's glog/gflags "
                "libraries (a Linux distribution's build): loading pycolmap beside them would "
                "close Blender. Use a Blender from blender.org")
    return None


def import_pycolmap() -> ModuleType:
    """pycolmap, or a ColmapError saying why it cannot be had here (the ImportError, if any,
    as its cause)."""
    refusal = pycolmap_refusal()
    if refusal is not None:
        raise ColmapError(f"COLMAP import and training need pycolmap: {refusal}")
    try:
        import pycolmap
    except ImportError as error:
        raise ColmapError(
            "COLMAP import and training need pycolmap 4.x, which this Blender cannot load "
            f"({error}): PyPI has no pycolmap for this platform or Python version, so the "
            "extension could not bundle one (README: Installing in Blender)") from error
    return pycolmap
