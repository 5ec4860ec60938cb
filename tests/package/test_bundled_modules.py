"""Every module the add-on imports is one every Blender has, or one the extension zip bundles
(scripts/build_extension.py, BUNDLED): a new import that neither covers would work in this venv
and fail for users of the installed extension."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "scripts"))

import build_extension  # noqa: E402

# In every Blender: its own modules, and numpy (official builds bundle it, distributions
# depend on it); splatcore is this project's wheel in every zip.
IN_BLENDER = {"bpy", "bpy_extras", "mathutils", "gpu", "gpu_extras", "bmesh", "bl_math",
              "bl_ui", "addon_utils", "idprop", "numpy", "splatcore"}


def addon_imports() -> dict[str, set[str]]:
    """Top-level module name -> the add-on files that import it (absolute imports only)."""
    found: dict[str, set[str]] = {}
    for path in (ROOT / "addon").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                found.setdefault(name.split(".")[0], set()).add(str(path.relative_to(ROOT)))
    return found


def test_every_import_is_in_blender_or_bundled():
    third_party = {name: files for name, files in addon_imports().items()
                   if name not in sys.stdlib_module_names and name not in IN_BLENDER}
    missing = {name: sorted(files) for name, files in third_party.items()
               if name not in build_extension.BUNDLED}
    assert not missing, f"imported by the add-on but neither in Blender nor bundled: {missing}"
    # and the check sees the imports it must: the bundled ones are all really used
    assert set(build_extension.BUNDLED) <= set(third_party)
