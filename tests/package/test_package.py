"""The project's shape: a Blender-free core, and a native module built for the limited API."""

from __future__ import annotations

import re
import subprocess
import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_core_imports_without_bpy() -> None:
    # A plain Python process where `import bpy` (and mathutils) fails: every core module loads.
    code = (
        "import sys, pkgutil, importlib\n"
        "sys.modules['bpy'] = None; sys.modules['mathutils'] = None\n"
        f"sys.path.insert(0, {str(ROOT)!r})\n"
        "import addon, addon.core, addon.core.formats\n"
        "for pkg in (addon.core, addon.core.formats):\n"
        "    for m in pkgutil.iter_modules(pkg.__path__):\n"
        "        importlib.import_module(pkg.__name__ + '.' + m.name)\n"
        "print('ok')\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr


def test_native_module_is_abi3() -> None:
    import splatcore

    assert Path(splatcore.__file__).name == "splatcore.abi3.so" or sys.platform == "win32"


def test_native_builds_as_abi3_wheel(tmp_path: Path) -> None:
    # `pip wheel native/` is how the extension zip gets its binary: one cp311-abi3 wheel that
    # every Blender from 4.2 (Python 3.11) on can load.
    done = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation",
         "-w", str(tmp_path), str(ROOT / "native")],
        capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    wheels = list(tmp_path.glob("splatcore-*.whl"))
    assert len(wheels) == 1 and "-cp311-abi3-" in wheels[0].name, wheels
    with zipfile.ZipFile(wheels[0]) as wheel:
        assert any(name.endswith(".abi3.so") or name.endswith(".pyd") for name in wheel.namelist())


def test_each_native_build_has_its_own_wheel_version() -> None:
    """Blender keeps an extension's wheel whose dist-info folder it already has: a rebuilt module
    under the same version must not be kept, so the module's hash is the version's local label."""
    from scripts import build_native

    one, other = build_native.wheel_version(b"module one"), build_native.wheel_version(b"two")
    assert re.fullmatch(re.escape(build_native.version()) + r"\+[0-9a-f]{12}", one), one
    assert one != other and one == build_native.wheel_version(b"module one")
