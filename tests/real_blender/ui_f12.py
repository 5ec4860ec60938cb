"""Runs inside a real Blender's UI (under Xvfb): F12 as a user presses it (the render job runs
in its own thread), then saves the Render Result and quits. Exits 1 if the splats' composite
read the meshes' render any other way than through Blender's render cache: in the UI the
render thread must not save the Render Result image the window is drawing (see the docstring
of the add-on's `blender/render/layers.py`).

    blender FILE.blend --python ui_f12.py -- [...] OUT.png
"""

from __future__ import annotations

import os
import sys
import time
import traceback

import bpy

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ui_kit import addon_module  # noqa: E402

OUT = sys.argv[-1]  # the last argument (another script may read the first ones)
state = {"started": None}


def fail(message: str) -> None:
    print(f"ui_f12: FAIL {message}", flush=True)
    os._exit(1)


def step():
    if state["started"] is None:
        window = bpy.context.window_manager.windows[0]
        with bpy.context.temp_override(window=window):
            bpy.ops.render.render("INVOKE_DEFAULT")
        state["started"] = time.monotonic()
        return 1.0
    if bpy.app.is_job_running("RENDER") and time.monotonic() - state["started"] < 120:
        return 0.5
    stats = addon_module("render.hooks").last_stats
    if "read_ms" not in stats:
        fail(f"no splat composite was made (stats {stats})")
    if "save_ms" in stats:
        fail(f"the render thread saved the Render Result ({stats['save_ms']:.1f} ms) instead "
             f"of reading the render cache")
    image = bpy.data.images.get("Render Result")
    if image is None:
        fail("no Render Result")
    scene = bpy.context.scene
    scene.render.image_settings.file_format = "PNG"
    image.save_render(OUT, scene=scene)
    print(f"ui_f12: saved {OUT}, the meshes read from the render cache in "
          f"{stats['read_ms']:.1f} ms", flush=True)
    bpy.ops.wm.quit_blender()
    return None


def guarded_step():
    try:
        return step()
    except Exception:  # a failure, not a Blender left open until the step's timeout
        fail(traceback.format_exc())


bpy.app.timers.register(guarded_step, first_interval=3.0)
