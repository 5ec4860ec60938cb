"""Runs inside a real Blender's UI (under Xvfb): Train Gaussians as the dialog's Train button
runs it, and each update of the training shown in the 3D view without a redraw first: at the
update the view's image of the new splats is asked for (`viewport.refresh`, from the real
window's regions), and the one redraw after it draws that image.

    blender START.blend --python training_view.py -- COLMAP_DIR OUT.json

Updates are not paced by their cost here (`job_runner.UPDATE_SHARE` 1: one every 3 s), so
that three come within a short run. OUT.json: per update after the first (which makes the
object), whether the view's key changed inside the update (a render asked for) and how many
images were drawn until the one of that key (1: the first redraw after the update drew it);
`ok` when F12's helper scene was there at the click (made by the import, or by the click
when the import's is gone), the scene was bridged in the same update as the training's object
(not at the click, not after) and every update asked for its image and drew it.
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
COLMAP, OUT = args[0], args[1]
UPDATES = 3
record: dict = {"version": list(bpy.app.version), "updates": [], "errors": []}


viewport = ui_kit.addon_module("viewport")
bridge = ui_kit.addon_module("render.compositor_bridge")
job_runner = ui_kit.addon_module("job_runner")
drawn: list[tuple] = []  # the draw keys of the images drawn, in order


def region_id() -> int:
    return ui_kit.view3d(bpy)[2].as_pointer()


def watch_draws():
    draw_image = viewport.draw_image

    def counted(image, cache_key=None):
        drawn.append(image.key)
        return draw_image(image, cache_key)
    viewport.draw_image = counted
    job_runner.UPDATE_SHARE = 1.0


def import_scene():
    with ui_kit.override(bpy):
        result = bpy.ops.splat.import_colmap(directory=COLMAP)
    if "FINISHED" not in result:
        raise RuntimeError(f"import_colmap: {result}")
    record["helper_after_import"] = bridge.helper_scene(create=False) is not None


def without_splats():
    """The scene's own splats and its F12 bridge (with the helper scene) removed: training's
    object will be its first, and the helper the import's."""
    for obj in [o for o in bpy.context.scene.objects if o.splat.is_splat]:
        bpy.data.objects.remove(obj)
    bridge.remove_bridge(bpy.context.scene)


def start_training():
    scene = bpy.context.scene
    record["bridged_before"] = bridge.bridge_node(scene) is not None
    with ui_kit.override(bpy):
        result = bpy.ops.splat.train("EXEC_DEFAULT", interactive=True, update_every=50)
    if "RUNNING_MODAL" not in result:
        raise RuntimeError(f"train: {result}")
    # F12's helper scene is made by the click at the latest; the scene is bridged in the same
    # update as the object appears, seen from that update's handler (issue 36).
    record["helper_at_click"] = bridge.helper_scene(create=False) is not None
    record["bridged_at_click"] = bridge.bridge_node(scene) is not None
    running = next(iter(job_runner.RUNNING.values()))

    def first_update_with_the_object(_scene, _depsgraph=None):
        if running.target() is not None and "bridged_with_object" not in record:
            record["bridged_with_object"] = bridge.bridge_node(scene) is not None
    bpy.app.handlers.depsgraph_update_post.append(first_update_with_the_object)
    apply = running.apply

    def watched(step, gaussians):
        made = running.target() is not None
        state = viewport._views.get(region_id())
        before = state.key if state is not None else None
        draws = len(drawn)
        apply(step, gaussians)
        if made:
            state = viewport._views.get(region_id())
            record["updates"].append({
                "step": step, "asked": state is not None and state.key != before,
                "key": state.key if state is not None else None, "draws_before": draws})
    running.apply = watched


def wait_for_updates():
    """A step: until UPDATES updates after the first have been shown and drawn (90 s at most)."""
    deadline = record.setdefault("deadline", time.monotonic() + 90.0)
    updates = record["updates"]
    if len(updates) >= UPDATES and updates[-1]["key"] in drawn:
        return None
    if time.monotonic() > deadline:
        record["errors"].append(f"{len(updates)} updates in 90 s")
        return None
    return 0.25


def stop_training():
    with ui_kit.override(bpy):
        bpy.ops.splat.train_stop()


def wait_until_stopped():
    return 0.5 if job_runner.RUNNING else None


def finish():
    for update in record["updates"]:
        key = update.pop("key")
        later = drawn[update.pop("draws_before"):]
        update["draws_until_drawn"] = later.index(key) + 1 if key in later else None
    record.pop("deadline", None)
    record["ok"] = not record["errors"] and record.get("helper_after_import", False) and \
        not record.get("bridged_before", True) and record.get("helper_at_click", False) and \
        not record.get("bridged_at_click", True) and record.get("bridged_with_object", False) and \
        len(record["updates"]) >= UPDATES and all(
        u["asked"] and u["draws_until_drawn"] is not None for u in record["updates"])
    with open(OUT + ".tmp", "w") as f:
        json.dump(record, f, indent=1)
    os.replace(OUT + ".tmp", OUT)


ui_kit.run_steps(bpy, [watch_draws, without_splats, import_scene, start_training, wait_for_updates,
                       stop_training, wait_until_stopped], finish, record["errors"])
