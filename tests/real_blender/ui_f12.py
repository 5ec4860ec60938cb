"""Runs inside a real Blender's UI (under Xvfb): F12 as a user presses it (the render job runs
in its own thread), then saves the Render Result and quits.

    blender FILE.blend --python ui_f12.py -- [...] OUT.png
"""

from __future__ import annotations

import sys
import time

import bpy

OUT = sys.argv[-1]  # the last argument (another script may read the first ones)
state = {"started": None}


def step():
    if state["started"] is None:
        window = bpy.context.window_manager.windows[0]
        with bpy.context.temp_override(window=window):
            bpy.ops.render.render("INVOKE_DEFAULT")
        state["started"] = time.monotonic()
        return 1.0
    if bpy.app.is_job_running("RENDER") and time.monotonic() - state["started"] < 120:
        return 0.5
    image = bpy.data.images.get("Render Result")
    scene = bpy.context.scene
    scene.render.image_settings.file_format = "PNG"
    image.save_render(OUT, scene=scene)
    print(f"ui_f12: saved {OUT}", flush=True)
    bpy.ops.wm.quit_blender()
    return None


bpy.app.timers.register(step, first_interval=3.0)
