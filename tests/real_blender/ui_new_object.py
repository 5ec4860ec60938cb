"""Runs inside a real Blender's UI (under Xvfb): the main thread's stalls after one new object
appears, Blender's Add Cube against a splat object as training makes it, with the scene's F12
bridge (and its helper scene) set up in the ways the add-on could set them up (issue 36).

    blender START.blend --python ui_new_object.py -- COLMAP_DIR SPLATS.ply OUT.json [ROUNDS]

The imported COLMAP scene, then ROUNDS rounds of: each kind below, the object removed after
4 s and the next 4 s later. A stall: more than 50 ms between two calls of a 10 ms timer.
OUT.json: per kind, each trial's stalls (ms, in order). A benchmark, never a test:
benchmarks/bench_ui_new_object_blender.sh runs it and prints the table.
"""

from __future__ import annotations

import json
import os
import sys
import time

import bpy

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # ui_kit, copied beside this
import ui_kit  # noqa: E402

args = sys.argv[sys.argv.index("--") + 1:]
COLMAP, PLY, OUT = args[0], args[1], args[2]
ROUNDS = int(args[3]) if len(args) > 3 else 3
WAIT = 4.0
KINDS = {
    "cube": "Add Cube (Blender's own)",
    "unbridged": "splat object, the scene bridged after it by a timer (until 0b305a5)",
    "bridged_before": "splat object, the scene bridged 4 s before (0b305a5: at the click)",
    "bridged_with": "splat object, the helper scene made and the scene bridged in its update",
    "helper_before": "splat object, the helper made 4 s before, the scene bridged in its update "
                     "(now)",
}
record: dict = {"version": list(bpy.app.version), "kinds": KINDS,
                "trials": {k: [] for k in KINDS}, "errors": []}
stalls: list[float] = []
last = [time.perf_counter()]


def tick() -> float:
    now = time.perf_counter()
    if now - last[0] > 0.05:
        stalls.append(round((now - last[0]) * 1000.0))
    last[0] = now
    return 0.01


bpy.app.timers.register(tick, first_interval=0.01, persistent=True)
bridge = ui_kit.addon_module("render.compositor_bridge")
hooks = ui_kit.addon_module("render.hooks")
operator = ui_kit.addon_module("train.operator")
gaussians: list = []


def import_scene():
    import importlib

    with ui_kit.override(bpy):
        if "FINISHED" not in bpy.ops.splat.import_colmap(directory=COLMAP):
            raise RuntimeError("import_colmap failed")
    root = operator.__name__.rsplit(".blender.", 1)[0]
    gaussians.append(importlib.import_module(root + ".core.formats.registry").read(PLY)[0])


def trial(kind: str):
    """A step: set the bridge up as `kind` has it, add the object, record the stalls over
    WAIT s, remove it, wait WAIT s."""
    phase = {"at": 0}

    def step():
        scene = bpy.context.scene
        phase["at"] += 1
        if phase["at"] == 1:  # the bridge as the kind has it
            bridge.remove_bridge(scene)  # and the helper scene with it
            if kind == "bridged_before":
                bridge.ensure_bridge(scene)
            elif kind == "helper_before":
                hooks.make_helper_ahead(scene)
            return WAIT
        if phase["at"] == 2:
            stalls.clear()
            if kind == "cube":
                with ui_kit.override(bpy):
                    bpy.ops.mesh.primitive_cube_add(location=(0.0, 0.0, -100.0))
                phase["object"] = bpy.context.active_object.name
            else:
                obj = operator.write_splats("ui_new_object", gaussians[0])
                if kind in ("bridged_with", "helper_before"):
                    hooks.bridge_new_splats(obj)
                phase["object"] = obj.name
            return WAIT
        if phase["at"] == 3:
            record["trials"][kind].append(list(stalls))
            bpy.data.objects.remove(bpy.data.objects[phase["object"]])
            return WAIT
        return None
    return step


def finish():
    with open(OUT + ".tmp", "w") as f:
        json.dump(record, f)
    os.replace(OUT + ".tmp", OUT)


ui_kit.run_steps(bpy, [import_scene] + [trial(k) for _ in range(ROUNDS) for k in KINDS],
                 finish, record["errors"])
