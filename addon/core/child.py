"""A module of the add-on run in a child process of the same Python, for work that must not
run in Blender's own process: COLMAP (pycolmap cannot load beside the system's glog/gflags in a
Linux distribution's Blender, and its long calls hold Python's lock) and anything a crash in
which must not take the user's unsaved work with it.

    argv = python_command("cli", ["reconstruct", src, "--out", dst, "--json"])
    subprocess.run(argv, env=environment())      # runs <package>.cli.main([...])

The child is `sys.executable` (Blender's own Python in an official Blender, the distribution's
in Debian's, the venv's with the bpy wheel) with this process's module path, so it imports the
extension's wheels as Blender does. It imports the add-on's package by its folder name: a plain
Python process has no `bl_ext` namespace, and the package's `__init__` imports nothing of
Blender.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1]  # the add-on's package folder
# The package's name in this process ("addon" in a checkout, "bl_ext.user_default.<id>" in an
# installed extension); in a child it is the folder's name.
PACKAGE_MODULE = __name__.rsplit(".", 2)[0]
_BOOT = ("import importlib, sys; sys.path.insert(0, sys.argv[1]); "
         "sys.exit(importlib.import_module(sys.argv[2]).main(sys.argv[3:]))")


def python_command(module: str, args: list[str]) -> list[str]:
    """The command that runs `<package>.<module>.main(args)` in a new Python process."""
    return [sys.executable, "-c", _BOOT, str(PACKAGE.parent), f"{PACKAGE.name}.{module}",
            *map(str, args)]


def module_here(module: str) -> str:
    """A module name as a child process knows it, as this process does (pickled classes)."""
    prefix = PACKAGE.name + "."
    return PACKAGE_MODULE + module[len(PACKAGE.name):] if module.startswith(prefix) else module


def environment() -> dict[str, str]:
    """This process's environment with its module path, so the child imports what it does."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p and os.path.isdir(p))
    env["PYTHONIOENCODING"] = "utf-8"
    return env
