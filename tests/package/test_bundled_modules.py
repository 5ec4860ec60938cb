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


def test_an_abi3_wheel_fetched_for_each_python_goes_into_the_zip_once(tmp_path):
    """av and splatcore are one abi3 wheel for every Python; fetched per Python, each copy lies
    in that Python's cache folder, and the zip must hold it once (a second entry of the same
    name is a broken zip and 36 MB more)."""
    import zipfile

    copies = []
    for python in ("3.11", "3.13"):
        wheel = tmp_path / python / "av-18.1.0-cp311-abi3-manylinux_2_28_x86_64.whl"
        wheel.parent.mkdir()
        wheel.write_bytes(b"wheel")
        copies.append(wheel)
    zip_path = build_extension.build_zip(tmp_path / "dist", "linux-x64", copies)
    with zipfile.ZipFile(zip_path) as archive:
        wheels = [n for n in archive.namelist() if n.startswith("wheels/")]
    assert wheels == ["wheels/av-18.1.0-cp311-abi3-manylinux_2_28_x86_64.whl"]
