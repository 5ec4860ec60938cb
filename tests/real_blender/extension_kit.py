"""Checks against the installed extension from inside a Blender that has nothing but bpy: the
`check` that prints PASS/FAIL lines, the extension's modules, installing the zip. Shared by
scripts/test_installed_extension.py's stages and splats53.py (staged beside them): plain
Python, no imports from this project, since each runs in that Blender's own Python."""

from __future__ import annotations

import importlib
import time
import traceback
from pathlib import Path

EXTENSION = "bl_ext.user_default.gaussian_splatting"
FAILURES: list[str] = []  # the names of the checks that failed, in order


class check:
    """`with check("name") as c:` prints `PASS name: c.detail, seconds` or `FAIL name: the error
    (at file:line)`; a failure is recorded in FAILURES and the next check still runs."""

    def __init__(self, name: str):
        self.name, self.detail = name, ""

    def __enter__(self):
        self.t0 = time.perf_counter()
        return self

    def __exit__(self, kind, error, tb):
        seconds = f"{time.perf_counter() - self.t0:.1f} s"
        if error is None:
            print(f"PASS {self.name}: {self.detail + ', ' if self.detail else ''}{seconds}",
                  flush=True)
        else:
            FAILURES.append(self.name)
            where = traceback.extract_tb(tb)[-1]
            message = " ".join(f"{kind.__name__}: {error}".split())[:800]
            print(f"FAIL {self.name}: {message} (at {Path(where.filename).name}:{where.lineno})",
                  flush=True)
            traceback.print_exception(kind, error, tb)
        return True


def ext(name: str):
    """The installed extension's module `name` ("blender.sources.gather", "core.transform")."""
    return importlib.import_module(f"{EXTENSION}.{name}")


def install_zip(bpy, zip_path: Path) -> None:
    """Preferences > Get Extensions > Install from Disk, enabled on install (a check)."""
    with check("install the zip"):
        result = bpy.ops.extensions.package_install_files(
            filepath=str(zip_path), repo="user_default", enable_on_install=True)
        assert result == {"FINISHED"}, result
        assert EXTENSION in bpy.context.preferences.addons, "not enabled after installing"
