"""The optional Python modules some features need, checked before the work starts.

Blender's official builds bundle numpy, OpenImageIO and zstandard; Linux distributions' builds
use the system Python and may lack them; pycolmap and xatlas ship with the extension's wheels
where the platform has them. A feature calls `require(module, feature)` before doing anything:
when the module cannot be imported, `MissingModule` (an `ImportError`) says in words a user can
act on which feature needs which module, and why the import failed. Operators catch it and
`self.report({'ERROR'}, str(error))`; final renders fail with it (see `render_failures`).
"""

from __future__ import annotations

import importlib
import sys

# What to install for each module (pip names differ from import names).
_PIP_NAMES = {"OpenImageIO": "OpenImageIO", "pycolmap": "pycolmap", "xatlas": "xatlas",
              "zstandard": "zstandard", "splatcore": "the extension's splatcore wheel"}


class MissingModule(ImportError):
    """A feature's Python module cannot be imported."""


def available(module: str) -> bool:
    try:
        require(module, "")
    except MissingModule:
        return False
    return True


def require(module: str, feature: str) -> None:
    """Raise `MissingModule` unless `module` imports; `feature` names what needs it."""
    try:
        if module == "pycolmap":  # its one import, which refuses a Blender it would close
            from ..core.colmap.errors import import_pycolmap
            import_pycolmap()
        else:
            importlib.import_module(module)
    except Exception as error:  # noqa: BLE001 - see `available`
        what = _PIP_NAMES.get(module, module)
        python = f"Python {sys.version_info.major}.{sys.version_info.minor}"
        hint = ("reinstall the Gaussian Splatting extension for this platform"
                if module == "splatcore" else
                f"install an extension build that bundles {what} for this platform, or "
                f"install {what} into Blender's {python}")
        raise MissingModule(f"{feature} needs the Python module '{module}', which this "
                            f"Blender cannot import ({error}); {hint}") from error
