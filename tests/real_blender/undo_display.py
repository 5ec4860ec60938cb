"""Runs inside a real Blender's UI (under Xvfb, started with --enable-event-simulate): the splat
object's display through import, Clean Up, undo and redo, as a user does it.

    blender --enable-event-simulate EMPTY.blend --python undo_display.py -- SPLATS.ply OUT_DIR

Steps (the operators as the menus run them, with an undo step each; Ctrl+Z, Ctrl+Shift+Z and
Tab as key presses the keymap handles):

    import       File > Import > Gaussian Splats
    clean_up     Object > Gaussian Splats > Clean Up (its defaults)
    undo         Ctrl+Z              (back to the import)
    redo         Ctrl+Shift+Z        (the clean-up again)
    edit_delete  Tab, Select Random, Delete Vertices (Edit Mode: its points show, by design)
    edit_undo    Ctrl+Z              (the delete undone, still in Edit Mode)
    undo_edit    Ctrl+Z              (out of Edit Mode, back to the object as it was)
    control_dots the object's Display As set to Textured (Blender's dots; the check must see them)

After each, once the add-on's viewport image has arrived at full resolution and the screen has
settled: OUT_DIR/<step>.png (the X screen), OUT_DIR/<step>.npz (the splats the viewport shows,
world space) and an entry in OUT_DIR/steps.json (the view's matrices, render options, the
object's display type and mode). `check.py undo OUT_DIR` holds each screenshot against the
native render of those splats from that view: vertex dots are pixels far off it.
"""

from __future__ import annotations

import importlib
import json
import os
import sys
import time

import bpy
import numpy as np
from mathutils import Quaternion, Vector

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # ui_kit, copied beside this
import ui_kit  # noqa: E402

ADDON = "bl_ext.user_default.gaussian_splatting"
args = sys.argv[sys.argv.index("--") + 1:]
PLY, OUT = args[0], args[1]
viewport = importlib.import_module(ADDON + ".blender.viewport")
record: dict = {"steps": [], "errors": [], "version": list(bpy.app.version)}
NAME = os.path.splitext(os.path.basename(PLY))[0]


def view3d():
    return ui_kit.view3d(bpy)


def press(key: str, *, ctrl: bool = False, shift: bool = False) -> None:
    """A key press and release as the window gets it, the mouse over the 3D view."""
    window, area, region = view3d()
    x, y = region.x + region.width // 2, region.y + region.height // 2
    window.event_simulate(type="MOUSEMOVE", value="NOTHING", x=x, y=y)
    window.event_simulate(type=key, value="PRESS", ctrl=ctrl, shift=shift, x=x, y=y)
    window.event_simulate(type=key, value="RELEASE", ctrl=ctrl, shift=shift, x=x, y=y)


def set_up() -> None:
    window, area, region = view3d()
    with ui_kit.override(bpy):
        bpy.ops.screen.screen_full_area(use_hide_panels=True)
    window, area, region = view3d()
    space = area.spaces.active
    space.shading.type = "SOLID"
    overlay = space.overlay
    overlay.show_floor = False
    overlay.show_axis_x = overlay.show_axis_y = overlay.show_axis_z = False
    overlay.show_cursor = False
    overlay.show_text = False
    space.show_gizmo = False
    space.lens = 50.0
    space.clip_start, space.clip_end = 0.05, 100.0
    rv3d = space.region_3d
    rv3d.view_perspective = "PERSP"
    # Looking at the origin from -Y, a little above (the imported object stands upright).
    rv3d.view_rotation = Quaternion((1, 0, 0), 1.35)
    rv3d.view_location = Vector((0.0, 0.0, 0.0))
    rv3d.view_distance = 4.0
    bpy.context.scene.splat_render.viewport = True


def act(name: str):
    def run():
        record["_step"] = name
        if name == "import":
            with ui_kit.override(bpy):
                bpy.ops.splat.import_splats("EXEC_DEFAULT", True, filepath=PLY)
        elif name == "clean_up":
            with ui_kit.override(bpy):
                bpy.ops.splat.clean_up("EXEC_DEFAULT", True)
        elif name in ("undo", "edit_undo", "undo_edit"):
            press("Z", ctrl=True)
        elif name == "redo":
            press("Z", ctrl=True, shift=True)
        elif name == "control_dots":
            # Not one of the user's steps: Display As Textured (as a user may pick it, which the
            # add-on leaves alone), to show the check sees vertex dots (its figure must fail here).
            bpy.data.objects[NAME].display_type = "TEXTURED"
        elif name == "edit_delete":
            press("TAB")
            # Tab is handled as the event queue runs: the rest comes in the next step.
            record["_after_tab"] = True
        view3d()[1].tag_redraw()
        return None
    return run


def edit_delete():
    if bpy.context.mode != "EDIT_MESH":
        raise RuntimeError(f"Tab did not enter Edit Mode (mode {bpy.context.mode})")
    with ui_kit.override(bpy):
        # Selecting pushes no undo step here (the user's X > Vertices after Tab is one step).
        bpy.ops.mesh.select_all(action="DESELECT")
        bpy.ops.mesh.select_random(ratio=0.5, seed=7)
        bpy.ops.mesh.delete("EXEC_DEFAULT", True, type="VERT")
    view3d()[1].tag_redraw()
    return None


def wait_for_image():
    """Until the add-on's full-resolution image of the current view and splats is drawn."""
    window, area, region = view3d()
    area.tag_redraw()
    state = viewport._views.get(region.as_pointer())
    image = viewport.renderer.result(region.as_pointer())
    # (Also in Edit Mode: an unchanged edit mesh keeps its key, so the view comes to rest.)
    current = state is not None and image is not None and image.key == state.key
    if not current or image.coarse or viewport.renderer.busy():
        if time.monotonic() - record.setdefault("_t0", time.monotonic()) > 60:
            record["errors"].append(f"{record.get('_step')}: no full-resolution viewport image "
                                    f"within 60 s")
            record.pop("_t0", None)
            return None
        return 0.5
    record.pop("_t0", None)
    return None


def settled_shot(name: str):
    """Screenshots a second apart until three in a row are the same (at most 60 s)."""
    path = os.path.join(OUT, f"{name}.png")
    state = {"previous": None, "same": 0, "t0": None}

    def step():
        now = time.monotonic()
        state["t0"] = state["t0"] or now
        ui_kit.shot(path)
        data = open(path, "rb").read()
        state["same"] = state["same"] + 1 if data == state["previous"] else 0
        state["previous"] = data
        if state["same"] >= 2 or now - state["t0"] > 60:
            return None
        view3d()[1].tag_redraw()
        return 1.0
    return step


def save_state(name: str):
    def step():
        window, area, region = view3d()
        rv3d = area.spaces.active.region_3d
        scene = bpy.context.scene
        obj = bpy.data.objects.get(NAME)
        found = viewport.viewport_splats(bpy.context.evaluated_depsgraph_get(), scene)
        entry = {"name": name, "mode": bpy.context.mode,
                 "display_type": obj.display_type if obj is not None else None,
                 "points": len(obj.data.vertices) if obj is not None else 0,
                 "region": [region.width, region.height],
                 "view_matrix": [list(r) for r in rv3d.view_matrix],
                 "window_matrix": [list(r) for r in rv3d.window_matrix]}
        if found is not None:
            gaussians, options = found
            np.savez(os.path.join(OUT, f"{name}.npz"), **gaussians.arrays())
            entry["options"] = options
            entry["splats"] = len(gaussians)
        record["steps"].append(entry)
        print(f"undo_display: {name}: {entry['mode']}, display {entry['display_type']}, "
              f"{entry['points']} points", flush=True)
        return None
    return step


steps: list = [lambda: (set_up(), None)[1]]
STEPS = ("import", "clean_up", "undo", "redo", "edit_delete", "edit_undo", "undo_edit",
         "control_dots")
for step_name in STEPS:
    steps.append(act(step_name))
    if step_name == "edit_delete":
        steps.append(edit_delete)
    steps.extend([wait_for_image, settled_shot(step_name), save_state(step_name)])


def finish() -> None:
    json.dump({k: v for k, v in record.items() if not k.startswith("_")},
              open(os.path.join(OUT, "steps.json"), "w"), indent=1)


ui_kit.run_steps(bpy, steps, finish, record["errors"], pause=0.3)
