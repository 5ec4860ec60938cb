"""The optional Python modules some features need: checked before the work starts, and before
the button is even enabled.

Blender's official builds bundle numpy, OpenImageIO and zstandard; Linux distributions' builds
use the system Python and may lack them; pycolmap and xatlas ship with the extension's wheels
where PyPI has them for the platform and Python (the installed extension's manifest lists the
wheels it carries).

- `require(module, feature)`, called before a feature does anything: when the module cannot be
  imported, `MissingModule` (an `ImportError`) says in words a user can act on which feature
  needs which module, why it cannot be had, and the one thing to do about it (never an install
  that cannot exist, such as a module for a Python no build of it is made for). Operators catch
  it and `self.report({'ERROR'}, str(error))`; final renders fail with it (`render.failures`).
- `unavailable(modules, feature)`, cheap (no import): the reason the feature cannot work in this
  Blender, or None. Operators' `poll` uses it through `poll_unavailable`, so their buttons are
  greyed out with the reason as the tooltip (`poll_message_set`), and the command line says it
  once, before running anything.
"""

from __future__ import annotations

import importlib
import importlib.util
import re
import sys
from pathlib import Path

# What to install for each module (pip names differ from import names).
_PIP_NAMES = {"OpenImageIO": "OpenImageIO", "pycolmap": "pycolmap", "xatlas": "xatlas",
              "zstandard": "zstandard", "splatcore": "splatcore", "av": "av"}
# The manifest of the installed extension (beside the add-on package); absent in a checkout.
MANIFEST = Path(__file__).resolve().parents[1] / "blender_manifest.toml"
_WHEEL = re.compile(r"wheels/([A-Za-z0-9_.]+?)-[^-/]+-(cp\d+|py\d+)-")

_cache: dict[str, str | None] = {}


class MissingModule(ImportError):
    """A feature's Python module cannot be imported."""


def python_version() -> str:
    return f"{sys.version_info.major}.{sys.version_info.minor}"


def bundled_pythons(module: str, manifest: Path | None = None) -> list[str] | None:
    """The Python versions ("3.11", ...) the installed extension carries `module`'s wheels for;
    None when not running from an installed extension (no manifest listing wheels)."""
    try:
        text = (manifest or MANIFEST).read_text(encoding="utf-8")
    except OSError:
        return None
    if "wheels" not in text:
        return None
    wanted = module.lower().replace("-", "_")
    versions = set()
    for name, tag in _WHEEL.findall(text):
        if name.lower() == wanted:
            versions.add("3" if tag.startswith("py") else f"{tag[2]}.{tag[3:]}")
    return sorted(versions, key=lambda v: tuple(int(p) for p in v.split(".")))


def _refusal(module: str) -> str | None:
    """Why `module` cannot be had at all (None: it may be tried). pycolmap refused in this
    process (a distribution's Blender) is no refusal when it is there for a child process of
    this Python: COLMAP work then runs there (`core.colmap.outside`, `core.sfm.process`)."""
    if module == "pycolmap":
        from ..core.colmap.errors import pycolmap_refusal
        refusal = pycolmap_refusal()
        if refusal is not None and importlib.util.find_spec("pycolmap") is not None:
            return None
        return refusal
    return None


def _hint(module: str) -> str:
    """The one thing a user can do about a module that is not there."""
    what = _PIP_NAMES.get(module, module)
    if module == "splatcore":
        return "reinstall the Gaussian Splatting extension for this platform"
    python = python_version()
    bundled = bundled_pythons(module)
    if bundled is None:  # a checkout or a copied add-on, not the installed extension
        return f"install {what} into the Python that runs Blender (Python {python})"
    if python in bundled:
        return ("the extension carries it for this Python but it did not load: reinstall the "
                "extension for this platform")
    if bundled:
        return (f"the extension carries {what} only for Python {', '.join(bundled)} (PyPI "
                f"had no {what} build for Python {python} on this platform when it was made): "
                f"use a Blender from blender.org, which runs one of those")
    return (f"PyPI had no {what} build for this platform when the extension was made: "
            f"use a Blender from blender.org on a platform {what} is built for")


def _message(module: str, feature: str, reason: str) -> str:
    return f"{feature} needs the Python module '{module}': {reason}"


def unavailable(modules, feature: str) -> str | None:
    """Why `feature` cannot work in this Blender (the first of `modules` that cannot be had),
    or None. Cheap and without importing anything new: a refusal, or a module Python cannot
    find (whether a found module then imports is `require`'s to say)."""
    for module in ((modules,) if isinstance(modules, str) else modules):
        loaded = sys.modules.get(module, False)
        if loaded is None:  # imports of it are blocked
            return _message(module, feature, f"this Blender cannot import it; {_hint(module)}")
        if loaded is not False:
            continue
        if module not in _cache:
            refusal = _refusal(module)
            if refusal is not None:
                _cache[module] = refusal
            elif importlib.util.find_spec(module) is not None:
                _cache[module] = None
            else:
                _cache[module] = f"this Blender cannot import it; {_hint(module)}"
        if _cache[module] is not None:
            return _message(module, feature, _cache[module])
    return None


def forget() -> None:
    """Check again (after installing a module)."""
    _cache.clear()


def poll_unavailable(cls, modules, feature: str) -> bool:
    """For an operator's `poll`: False, with the reason as its tooltip, when `feature` cannot
    work in this Blender."""
    reason = unavailable(modules, feature)
    if reason is not None and hasattr(cls, "poll_message_set"):
        cls.poll_message_set(reason)
    return reason is None


def poll_needs(cls, context=None) -> bool:
    """An operator's `poll` (`poll = classmethod(poll_needs)`) from its `needs`, a
    (modules, feature) pair: `poll_unavailable` of them."""
    return poll_unavailable(cls, *cls.needs)


def available(module: str) -> bool:
    try:
        require(module, "")
    except MissingModule:
        return False
    return True


def require(module: str, feature: str) -> None:
    """Raise `MissingModule` unless `module` imports; `feature` names what needs it."""
    refusal = _refusal(module)
    if refusal is not None:
        raise MissingModule(_message(module, feature, refusal))
    try:
        if module == "pycolmap":  # its one import, unless it is for child processes only
            from ..core.colmap.errors import import_pycolmap, pycolmap_refusal
            if pycolmap_refusal() is None:
                import_pycolmap()
        else:
            importlib.import_module(module)
    except Exception as error:  # noqa: BLE001 - see `available`
        cause = error.__cause__ if isinstance(error.__cause__, ImportError) else error
        raise MissingModule(_message(module, feature, f"this Blender cannot import it "
                                                      f"({cause}); {_hint(module)}")) from error
