"""Runs inside a real Blender's UI (under Xvfb): screenshots of the 3D viewport of the open file.

    blender FILE.blend --python viewport_shot.py -- OUT_DIR [SHADING ...]

The 3D view is made to fill the window (no header, no side bars), looks along the scene
camera from a little further back (or, with SPLAT_VIEW=FRONT|RIGHT|TOP, is that orthographic
view of the origin), floor grid and axes off, nothing selected. With SPLAT_TURN=FRONT|RIGHT|TOP
the view first rests at the perspective view with its full-resolution image, then turns to that
view as numpad 1/3/7 does (`view3d.view_axis`, smooth view on), and the shots are of the new
view; for 4 s after the turn, the screen showing an image of another view once the view has
rested is an error ("a stale view"). SPLAT_SLOW_RENDER=SECONDS delays every viewport render. For each shading
(SOLID, MATERIAL), once the add-on's viewport image has arrived at full resolution, it saves
OUT_DIR/<shading>_splats.png (splats shown), OUT_DIR/<shading>_plain.png (the add-on's drawing
switched off) and OUT_DIR/view.json (region size, view and projection matrices), then quits.
Errors raised in the draw handler are collected in view.json ("errors").
"""

from __future__ import annotations

import importlib
import json
import os
import sys
import time
import traceback

import bpy
from mathutils import Vector

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # ui_kit, copied beside this
import ui_kit  # noqa: E402
from ui_kit import shot  # noqa: E402,F401

ADDON = "bl_ext.user_default.gaussian_splatting"
args = sys.argv[sys.argv.index("--") + 1:]
OUT = args[0]
SHADINGS = args[1:] or ["SOLID"]
viewport = importlib.import_module(ADDON + ".blender.viewport")
errors: list[str] = []
record: dict = {"shots": {}}


def view3d():
    return ui_kit.view3d(bpy)


def set_up() -> None:
    window, area, region = view3d()
    with bpy.context.temp_override(window=window, area=area, region=region):
        bpy.ops.screen.screen_full_area(use_hide_panels=True)
    bpy.ops.object.select_all(action="DESELECT")
    bpy.context.scene.camera.hide_set(True)  # the view looks from behind it
    if os.environ.get("SPLAT_EDIT_MODE"):  # a look at Edit Mode (its points must show)
        splats = bpy.data.objects["Splats"]
        bpy.context.view_layer.objects.active = splats
        splats.select_set(True)
        bpy.ops.object.mode_set(mode="EDIT")


def aim() -> None:
    window, area, region = view3d()
    space = area.spaces.active
    space.overlay.show_floor = False
    space.overlay.show_axis_x = space.overlay.show_axis_y = space.overlay.show_axis_z = False
    space.overlay.show_cursor = False
    space.overlay.show_text = False
    space.show_gizmo = False
    space.lens = 50.0
    space.clip_start, space.clip_end = 0.1, 100.0
    rv3d = space.region_3d
    axis = os.environ.get("SPLAT_VIEW")  # FRONT, RIGHT, TOP: that orthographic view instead
    if axis:
        from mathutils import Euler
        rv3d.view_perspective = "ORTHO"
        angles = {"FRONT": (1.5707963, 0, 0), "RIGHT": (1.5707963, 0, 1.5707963),
                  "TOP": (0, 0, 0)}[axis]
        rv3d.view_rotation = Euler(angles).to_quaternion()
        rv3d.view_distance = 3.0
        rv3d.view_location = Vector((0.0, 0.0, 0.0))
        for other in window.screen.areas:
            other.tag_redraw()
        return
    rv3d.view_perspective = "PERSP"
    camera = bpy.context.scene.camera
    # Look from the camera position, moved back by 1 unit: the splats fill the middle.
    rotation = camera.matrix_world.to_quaternion()
    rv3d.view_rotation = rotation
    rv3d.view_distance = 7.0
    rv3d.view_location = camera.matrix_world.translation + rotation @ Vector((0, 0, -6.0))
    for other in window.screen.areas:
        other.tag_redraw()


steps: list = []


def finish() -> None:
    json.dump({**{k: v for k, v in record.items() if not k.startswith("_")},
               "errors": errors + viewport.renderer.errors},
              open(os.path.join(OUT, "view.json"), "w"), indent=1)


def current_view(area, region) -> tuple:
    """The view part of the add-on's draw key for this 3D view (`viewport.view_of`)."""
    import numpy as np

    rv3d = area.spaces.active.region_3d
    return (np.array(rv3d.view_matrix).tobytes(), np.array(rv3d.window_matrix).tobytes(),
            region.width, region.height)


def wait_until_rested():
    window, area, region = view3d()
    image = viewport.renderer.result(region.as_pointer())
    compiling = bpy.app.is_job_running("SHADER_COMPILATION")  # Material Preview's shaders
    if image is None or image.coarse or viewport.renderer.busy() or compiling or \
            viewport.view_of(image.key) != current_view(area, region):
        if time.monotonic() - record.setdefault("_t0", time.monotonic()) > 60:
            errors.append("no full-resolution viewport image within 60 s")
            return None
        area.tag_redraw()
        return 0.5
    record.pop("_t0", None)
    return None


def settled_shot(path: str, at_least: float = 0.0):
    """A step: screenshot every second until three in a row are the same, and `at_least`
    seconds have passed since the shading was set (EEVEE draws meshes white while it compiles
    their shaders, with no job to wait for on 5.2), at most 90 s."""
    state = {"previous": None, "same": 0, "t0": None}

    def step():
        now = time.monotonic()
        state["t0"] = state["t0"] or now
        shot(path)
        data = open(path, "rb").read()
        state["same"] = state["same"] + 1 if data == state["previous"] else 0
        state["previous"] = data
        if (state["same"] >= 2 and now - record["_shading_set"] >= at_least) \
                or now - state["t0"] > 90:
            return None
        view3d()[1].tag_redraw()
        return 1.0
    return step


def add_shading(shading: str) -> None:
    def configure():
        window, area, region = view3d()
        area.spaces.active.shading.type = shading
        record["_shading_set"] = time.monotonic()
        bpy.context.scene.splat_render.viewport = True
        area.tag_redraw()
        return None

    def record_view():
        window, area, region = view3d()
        rv3d = area.spaces.active.region_3d
        record["region"] = [region.width, region.height]
        record["view_matrix"] = [list(r) for r in rv3d.view_matrix]
        record["window_matrix"] = [list(r) for r in rv3d.window_matrix]
        record["version"] = list(bpy.app.version)
        record["occludes"] = os.environ.get("SPLAT_VIEW", "FRONT") == "FRONT"
        return None

    def splats_off():
        bpy.context.scene.splat_render.viewport = False
        view3d()[1].tag_redraw()
        return None

    compile_time = 20.0 if shading == "MATERIAL" else 0.0
    steps.extend([configure, wait_until_rested, record_view,
                  settled_shot(os.path.join(OUT, f"{shading.lower()}_splats.png"), compile_time),
                  splats_off, settled_shot(os.path.join(OUT, f"{shading.lower()}_plain.png"))])


def catch_draw_errors():
    """Count exceptions raised by the draw handler (Blender prints and swallows them)."""
    real = viewport.draw_view

    def checked(context):
        try:
            real(context)
        except Exception:
            message = traceback.format_exc()
            if message not in errors:
                errors.append(message)
            raise
    viewport.draw_view = checked


catch_draw_errors()


def watch_stale_draws() -> None:
    """Keep what the 3D view last showed: the view of the image last drawn and the view it was
    drawn into (`_shown`); `stale_on_screen` polls it after the turn."""
    real = viewport.draw_image
    seen = {"view": None, "since": 0.0}
    record["draws_after_turn"] = 0

    def watched(image, cache_key=None):
        view = current_view(bpy.context.area, bpy.context.region)
        if view != seen["view"]:
            seen["view"], seen["since"] = view, time.monotonic()
        record["_shown"] = (viewport.view_of(image.key), view, seen["since"])
        record["draws_after_turn"] += bool(record.get("_turned"))
        return real(image, cache_key)
    viewport.draw_image = watched


def stale_on_screen(seconds: float = 4.0):
    """A step: for `seconds` after the turn, every 50 ms, whether the screen shows an image of
    another view (the last one drawn) while the view has rested (`viewport.REST_SECONDS` since
    it last changed, plus 0.3 s for Blender to redraw under Xvfb on a loaded machine): the time
    it did is an error."""
    state = {"t0": None, "stale": 0.0, "last": None}

    def step():
        now = time.monotonic()
        state["t0"] = state["t0"] or now
        window, area, region = view3d()
        shown = record.get("_shown")
        if shown is not None and shown[1] == current_view(area, region) and \
                shown[0] != shown[1] and now - shown[2] > viewport.REST_SECONDS + 0.3:
            state["stale"] += 0.05
        if now - state["t0"] < seconds:
            return 0.05
        record["stale_seconds"] = round(state["stale"], 2)
        if state["stale"] > 0:
            errors.append(f"a stale view: the view before was on screen {state['stale']:.2f} s "
                          f"after the new view rested")
        return None
    return step


def turn():
    window, area, region = view3d()
    bpy.context.preferences.view.smooth_view = 200   # numpad's animated turn
    with bpy.context.temp_override(window=window, area=area, region=region):
        bpy.ops.view3d.view_axis(type=os.environ["SPLAT_TURN"])
    record["_turned"] = True
    return None


steps.extend([lambda: (set_up(), None)[1], lambda: (aim(), None)[1]])
if os.environ.get("SPLAT_TURN"):
    watch_stale_draws()
    # Each viewport render takes this much longer, as a large scene on a busy machine does:
    # the previous view's picture stayed up when a render of the new view was still waiting as
    # the view came to rest.
    slow = float(os.environ.get("SPLAT_SLOW_RENDER", "0"))
    if slow:
        real_render = viewport.render_view

        def slow_render(*args, **kwargs):
            time.sleep(slow)
            return real_render(*args, **kwargs)
        viewport.render_view = slow_render

    def show_splats():
        view3d()[1].spaces.active.shading.type = "SOLID"
        bpy.context.scene.splat_render.viewport = True
        view3d()[1].tag_redraw()
        return None
    steps.extend([show_splats, wait_until_rested, turn, stale_on_screen()])
for name in SHADINGS:
    add_shading(name)
ui_kit.run_steps(bpy, steps, finish, errors)
