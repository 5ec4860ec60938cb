"""Pieces shared by the scripts that drive a real Blender's UI under Xvfb (viewport_shot.py,
undo_display.py; copied beside them): the 3D view, the X screen, and steps run from a timer.
Plain bpy, no imports from this project."""

from __future__ import annotations

import subprocess
import traceback
from typing import Callable


def view3d(bpy):
    """(window, area, region) of the first 3D view's main region."""
    for window in bpy.context.window_manager.windows:
        for area in window.screen.areas:
            if area.type == "VIEW_3D":
                region = next(r for r in area.regions if r.type == "WINDOW")
                return window, area, region
    raise RuntimeError("no 3D view")


def override(bpy):
    """A context override for operators run as from the first 3D view's main region."""
    window, area, region = view3d(bpy)
    return bpy.context.temp_override(window=window, area=area, region=region)


def addon_module(name: str):
    """The installed add-on's module `blender.<name>` (e.g. "viewport", "train.operator")."""
    import sys

    return sys.modules[next(m for m in sys.modules if m.endswith(".blender." + name))]


def shot(path: str) -> None:
    """The X screen (Blender's own screenshot reads a black front buffer under Xvfb)."""
    subprocess.run(["import", "-window", "root", path], check=True)


def run_steps(bpy, steps: list[Callable], finish: Callable[[], None], errors: list[str], *,
              pause: float = 0.5, first_interval: float = 2.0) -> None:
    """Run `steps` one after another from a timer: a step returns None when done, else the
    seconds to wait before it is called again. Then `finish()` and Blender quits. An exception
    is added to `errors` and ends the run (finish still runs)."""
    def tick():
        try:
            if not steps:
                finish()
                bpy.ops.wm.quit_blender()
                return None
            wait = steps[0]()
            if wait is None:
                steps.pop(0)
                return pause
            return wait
        except Exception:
            errors.append(traceback.format_exc())
            print(errors[-1], flush=True)
            steps.clear()
            return 0.1
    bpy.app.timers.register(tick, first_interval=first_interval)
