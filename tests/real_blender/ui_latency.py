"""Runs inside a real Blender's UI (under Xvfb): how late a 10 ms timer on Blender's main thread
runs while Train Gaussians runs as a user starts it (in the background: the modal timer, the
status bar, the splat object updated as it trains and drawn by the add-on's viewport).

    blender START.blend --python ui_latency.py -- COLMAP_DIR OUT.json [SECONDS]

Phases of SECONDS each, in order: nothing running (Blender's own lateness); the 3D view
redrawn every 0.25 s (what one redraw costs here); a cube added with Add > Mesh > Cube (what
Blender's own redraws after an object appears cost here); Train Gaussians with its defaults; the same
with the add-on's viewport drawing off; then training again with no updates of the object
(`Update Every` 0). OUT.json holds each phase's lateness in ms (every tick), the 3D view draws
counted (the add-on's draw handler), the training steps done, and a timeline of its stalls
over 50 ms, draws and object updates (time.perf_counter(), what, seconds). A benchmark, never a test:
benchmarks/bench_ui_latency_blender.sh runs it and prints the table.
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
SECONDS = float(args[2]) if len(args) > 2 else 30.0
PERIOD = 0.01
record: dict = {"version": list(bpy.app.version), "period_ms": PERIOD * 1000, "phases": {},
                "errors": []}
draws = [0]
events: list[tuple] = []  # (time.perf_counter(), what, seconds): stalls, draws, object updates


class Ticker:
    """A 10 ms timer that records how much later than asked each call came."""

    def __init__(self) -> None:
        self.late: list[float] | None = None
        self.last = 0.0
        bpy.app.timers.register(self.tick, first_interval=PERIOD, persistent=True)

    def tick(self) -> float:
        now = time.perf_counter()
        if self.late is not None:
            self.late.append((now - self.last - PERIOD) * 1000.0)
            if now - self.last > 0.05:
                events.append((round(self.last, 3), "stall", round(now - self.last, 3)))
        self.last = now
        return PERIOD

    def measure(self, name: str, extra=None):
        """A step: record SECONDS of lateness (and 3D view draws) under `name`."""
        state = {"end": None}

        def step():
            if state["end"] is None:
                state["end"] = time.perf_counter() + SECONDS
                self.late, draws[0] = [], 0
                events.clear()
                return 0.5
            if time.perf_counter() < state["end"]:
                return 0.5
            record["phases"][name] = {"late_ms": self.late, "draws": draws[0],
                                      "events": list(events), **(extra() if extra else {})}
            self.late = None
            return None
        return step


ticker = Ticker()


def count_draws():
    """Count the add-on's draw handler calls: one per redraw of the 3D view."""
    viewport = ui_kit.addon_module("viewport")
    draw_view = viewport.draw_view

    def counted(context):
        draws[0] += 1
        start = time.perf_counter()
        try:
            return draw_view(context)
        finally:
            events.append((round(start, 3), "draw", round(time.perf_counter() - start, 3)))
    viewport.draw_view = counted  # the handler looks the function up at each call
    operator = ui_kit.addon_module("train.operator")
    write_splats = operator.write_splats

    def timed_write(*args, **kwargs):
        start = time.perf_counter()
        try:
            return write_splats(*args, **kwargs)
        finally:
            events.append((round(start, 3), "update", round(time.perf_counter() - start, 3)))
    operator.write_splats = timed_write


def import_scene():
    with ui_kit.override(bpy):
        result = bpy.ops.splat.import_colmap(directory=COLMAP)
    if "FINISHED" not in result:
        raise RuntimeError(f"import_colmap: {result}")


def start_training(**settings):
    def step():
        with ui_kit.override(bpy):
            # What the dialog's Train button runs, in the background (interactive).
            result = bpy.ops.splat.train("EXEC_DEFAULT", interactive=True, **settings)
        if "RUNNING_MODAL" not in result:
            raise RuntimeError(f"train: {result}")
    return step


def training_steps() -> dict:
    job = next(iter(ui_kit.addon_module("job_runner").RUNNING.values()), None)
    if job is None:
        return {"steps": None, "note": "training was not running at the end"}
    return {"steps": job.progress.step, "gaussians": job.progress.gaussians}


def stop_training():
    with ui_kit.override(bpy):
        bpy.ops.splat.train_stop()


def wait_until_stopped():
    return 0.5 if ui_kit.addon_module("job_runner").RUNNING else None


def redraws(on: bool):
    """A step: tag the 3D view for redraw every 0.25 s, or stop doing so."""
    def tick():
        for window in bpy.context.window_manager.windows:
            for area in window.screen.areas:
                if area.type == "VIEW_3D":
                    area.tag_redraw()
        return 0.25 if record.get("redrawing") else None

    def step():
        record["redrawing"] = on
        if on:
            bpy.app.timers.register(tick)
    return step


def add_a_cube_soon():
    """Blender's own cost of an update that adds an object (Add > Mesh > Cube, 1 s into the
    next phase): the floor under the update that makes the splat object."""
    def add():
        with ui_kit.override(bpy):
            bpy.ops.mesh.primitive_cube_add(location=(0.0, 0.0, -100.0))
        record["cube"] = bpy.context.active_object.name
    bpy.app.timers.register(add, first_interval=1.0)


def remove_the_cube():
    bpy.data.objects.remove(bpy.data.objects[record.pop("cube")])


def settle(seconds: float = 3.0):
    """A step: wait for Blender's redraws after the last change (one per anti-aliasing sample,
    up to 2 s on a busy machine) to end before the next phase, so they are not counted in it."""
    state = {}

    def step():
        if "waited" in state:
            return None
        state["waited"] = True
        return seconds
    return step


def viewport(on: bool):
    def step():
        bpy.context.scene.splat_render.viewport = on
    return step


def finish():
    with open(OUT + ".tmp", "w") as f:
        json.dump(record, f)
    os.replace(OUT + ".tmp", OUT)


ui_kit.run_steps(bpy, [
    count_draws, import_scene, ticker.measure("idle"),
    redraws(True), ticker.measure("3D view redrawn every 0.25 s"), redraws(False),
    add_a_cube_soon, ticker.measure("a cube added (Blender's own update), then idle"),
    remove_the_cube, settle(),
    start_training(), ticker.measure("training", training_steps),
    viewport(False), ticker.measure("training, splats not in the viewport", training_steps),
    stop_training, wait_until_stopped, viewport(True),
    start_training(update_every=0), ticker.measure("training, no object updates", training_steps),
    stop_training, wait_until_stopped], finish, record["errors"])
