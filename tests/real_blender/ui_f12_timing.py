"""Runs inside a real Blender's UI (under Xvfb): F12 as a user presses it, RUNS times at WxH,
and writes how long each took (benchmarks/bench_ui_f12_blender.sh prints the table).

    blender FILE.blend --python ui_f12_timing.py -- OUT.json WxH RUNS MODE

MODE `cache`: the add-on as it is (the UI reads the meshes' render from Blender's render
cache). MODE `save_render`: the render thread saves the Render Result instead, as the add-on
did before 2026-11-29 (for the comparison only: that can hang Blender). MODE `meshes_only`:
the splat objects deleted and the compositor bridge removed (the add-on's own undo of it), so
the meshes' F12 alone; MODE `meshes_only_cache`: the same with the scene's Cache Result on
(what Blender's writing of its render cache costs by itself).
"""

from __future__ import annotations

import json
import os
import sys
import time

import bpy

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ui_kit import addon_module  # noqa: E402

OUT, SIZE, RUNS, MODE = sys.argv[sys.argv.index("--") + 1:][:4]
hooks = addon_module("render.hooks")
if MODE == "save_render":
    hooks.reads_render_cache = lambda: False
scene = bpy.context.scene
if MODE.startswith("meshes_only"):
    for obj in [o for o in scene.objects if o.name.startswith("Splats")]:
        bpy.data.objects.remove(obj)
    addon_module("render.compositor_bridge").remove_bridge(scene)
scene.render.resolution_x, scene.render.resolution_y = map(int, SIZE.split("x"))
scene.render.resolution_percentage = 100
runs: list[dict] = []
current: dict = {}


def mark(name: str):
    def handler(*_args) -> None:
        if "start" in current:
            current.setdefault(name, []).append(1000 * (time.monotonic() - current["start"]))
    return handler


# frame_change_post runs when each scene's render starts: the meshes' scene, then the helper
# scene in the compositor. Between the two: the meshes' render and what Blender does with it.
for event in ("frame_change_post", "render_complete"):
    getattr(bpy.app.handlers, event).append(mark(event))


def step():
    if "start" in current:
        now = time.monotonic()  # this timer's gaps: how long the main thread was away
        current["longest"] = max(current.get("longest", 0.0), now - current.get("tick", now))
        current["tick"] = now
        if bpy.app.is_job_running("RENDER"):
            return 0.02
        wall = 1000 * (time.monotonic() - current.pop("start"))
        starts = current.get("frame_change_post", [])
        runs.append({"wall_ms": wall,
                     "meshes_ms": starts[1] - starts[0] if len(starts) >= 2 else None,
                     "addon_ms": hooks.last_stats.get("total_ms"),
                     "saved": "save_ms" in hooks.last_stats,
                     "longest_stall_ms": 1000 * current.get("longest", 0.0)})
        current.clear()
        if len(runs) == int(RUNS):
            with open(OUT, "w") as file:
                json.dump({"version": list(bpy.app.version), "mode": MODE, "size": SIZE,
                           "runs": runs}, file)
            bpy.ops.wm.quit_blender()
            return None
        return 1.0
    if MODE.startswith("meshes_only"):
        scene.render.use_render_cache = MODE == "meshes_only_cache"
    window = bpy.context.window_manager.windows[0]
    with bpy.context.temp_override(window=window):
        bpy.ops.render.render("INVOKE_DEFAULT")
    current["start"] = time.monotonic()
    return 0.02


bpy.app.timers.register(step, first_interval=3.0)
