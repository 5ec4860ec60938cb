"""Long jobs from operators, one way: training, scene to splats and mesh conversion hand the
runner an `OperatorJob` and call `JobOperator.run_job` from their `execute`.

    class SPLAT_OT_something(JobOperator, bpy.types.Operator):
        interactive: BoolProperty(default=False, options={"HIDDEN", "SKIP_SAVE"})

        def invoke(self, context, event):
            self.interactive = wants_background(context)
            ...  # a settings dialog whose OK calls execute, or execute directly

        def execute(self, context):
            return self.run_job(context, OperatorJob("key", "Title", job, finish, ...))

The job is a `core.jobs.TrainingJob` (work on a worker thread) or a `core.jobs.StagedJob` (work
in small steps on the main thread, for jobs that touch Blender data). Either way:

- In the UI (`interactive`, set by `invoke` when there is a window): the job starts and a modal
  handler polls it from a 0.25 s timer on the main thread (bpy is not thread-safe: only the main
  thread touches Blender data; a `StagedJob` does its next steps there). The status bar shows a
  progress bar, the status line (`core.jobs.status_line`) and a stop button per job; snapshots
  (`job.take_snapshot`) go into the target object through `apply`, not while the object is in
  Edit Mode or a render locks the interface. Esc, the stop button or `splat.train_stop` stop
  the job after its current step; loading another file or disabling the add-on stops it too.
  Right-click does not stop it: the user keeps working meanwhile. The dialog's OK calls
  `execute`, which adds the timer and the modal handler and returns RUNNING_MODAL (as
  Blender's "Operator Modal Timer" template does).
- Blocking (scripts, `blender --background`, the bpy wheel): the job runs on the calling
  thread; with a window the cursor shows the progress (`wm.progress_begin/update`), without one
  a line is printed at every stage and at most every few seconds (`core.jobs.ProgressPrinter`).

At the end `finish(job, write)` (main thread) writes the result (not when `write` is False: the
object is in Edit Mode) and returns (level, message, object or None); the runner reports the
message (headless, Blender prints reports) and makes the object active.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Callable, Iterator

import bpy
from bpy.props import BoolProperty, StringProperty

from ..core.gaussians import Gaussians
from ..core.jobs import Progress, ProgressPrinter, StagedJob, TrainingJob, status_line
from .registration import register_classes, unregister_classes
from .render import hooks
from .threads import scene_threads

TIMER_STEP = 0.25  # seconds between polls of a background job
STAGE_BUDGET = 0.1  # seconds of main-thread work per poll for a StagedJob
# Seconds between two updates of a job's object on screen, at least, whatever its step interval:
# each update redraws the 3D view (once per Workbench anti-aliasing sample when it writes the
# object's data, once for the add-on's new image when training shows a snapshot in its place),
# 0.2-0.5 s a time in software OpenGL (Blender 4.3 under Xvfb), and a UI busy redrawing answers
# late.
SHOW_INTERVAL = 3.0
# ... and paced by what they cost: the main thread's stalls (over STALL seconds) in the
# COST_WINDOW seconds after an update, the object's write included, are at most this share of
# the time between updates (`StallProbe`). In Blender 4.3 under Xvfb (software OpenGL, 2 cores)
# an update of the walkthrough's splats brought nine redraws of 0.2-0.3 s, about 2 s of stalls:
# one update every 3 s kept the main thread stalled 47 % of the time; timing the redraws between
# the 3D view's own callbacks saw only two thirds of it (docs/benchmarks/training_sizes.md).
# A 3 % share leaves the UI's own stalls room under issue 36's 5 % of the time. At most
# MAX_SHOW_INTERVAL apart.
UPDATE_SHARE = 0.03
COST_WINDOW = 4.0
STALL = 0.05
MAX_SHOW_INTERVAL = 60.0
# The update that makes the object: training waits this long after it, while Blender redraws
# the view once per anti-aliasing sample (eight, 1-2 s in software OpenGL), so that those
# redraws have the cores to themselves (issue 36). Once per run.
NEW_OBJECT_HOLD = 2.0


class StallProbe:
    """The main thread's time lost to stalls over the next `seconds`: a timer every
    PROBE_PERIOD, and each gap between its calls longer than STALL counted whole (the measure of
    docs/benchmarks/training_sizes.md "By time, not by ticks"). Without an event loop (background
    mode) it never runs and counts nothing."""

    PROBE_PERIOD = 0.02

    def __init__(self, seconds: float) -> None:
        self.lost = 0.0
        self._last = time.monotonic()
        self._end = self._last + seconds
        bpy.app.timers.register(self._tick, first_interval=self.PROBE_PERIOD)

    def count(self, now: float) -> bool:
        """One timer call at `now`; False once the probe's time is over."""
        gap = now - self._last
        if gap > STALL:
            self.lost += gap
        self._last = now
        return now < self._end

    def _tick(self) -> float | None:
        return self.PROBE_PERIOD if self.count(time.monotonic()) else None


@dataclass
class OperatorJob:
    """A job as the runner, the modal handler and the status bar see it."""

    key: str  # one running job per key, e.g. "train:garden"
    title: str  # "Training", "Baking", "Converting to mesh"
    job: TrainingJob | StagedJob
    # main thread, at the end: write the result (when `write`); (level, message, object)
    finish: Callable[["OperatorJob", bool], tuple[str, str, object]]
    apply: Callable[[int, Gaussians], None] | None = None  # main thread: show a snapshot
    target: Callable[[], object] = lambda: None  # the object snapshots go into (or None)
    progress: Progress = field(default_factory=Progress)
    pending: tuple[int, Gaussians] | None = None
    shown_at: float = float("-inf")  # time.monotonic() of the last snapshot shown
    write_cost: float = 0.0  # main-thread seconds the last update's write took
    probe: StallProbe | None = None  # the stalls after it

    @property
    def show_cost(self) -> float:
        """Main-thread seconds the last update cost (so far)."""
        return self.write_cost + (self.probe.lost if self.probe is not None else 0.0)

    def next_show(self) -> float:
        """When the next snapshot may be shown (time.monotonic())."""
        return self.shown_at + min(MAX_SHOW_INTERVAL, max(SHOW_INTERVAL,
                                                          self.show_cost / UPDATE_SHARE))


RUNNING: dict[str, OperatorJob] = {}


def wants_background(context) -> bool:
    """Whether an operator invoked in `context` should run its job in the background."""
    return not bpy.app.background and getattr(context, "window", None) is not None


def is_running(prefix: str) -> bool:
    """Whether a job whose key starts with `prefix` is running."""
    return any(key.startswith(prefix) for key in RUNNING)


def make_active(context, obj) -> None:
    """Select `obj` alone and make it active, when it is in the context's view layer."""
    layer = getattr(context, "view_layer", None)
    if layer is None or obj is None:
        return
    layer.update()  # objects linked during the job show up in the layer after an update
    if layer.objects.get(obj.name) is None:
        return
    for other in list(context.selected_objects):
        if other != obj:
            other.select_set(False)
    obj.select_set(True, view_layer=layer)
    layer.objects.active = obj


@contextmanager
def preparing(context, title: str, stage: str) -> Iterator[Callable[[float, str], None]]:
    """Progress of main-thread work before a job (e.g. Cycles renders), as `(fraction, message)`:
    the cursor's counter with a window, terminal lines (the stage and its percentage) without."""
    wm = context.window_manager
    window = wants_background(context)
    printer = ProgressPrinter(title) if bpy.app.background else None

    def report(fraction: float, message: str) -> None:
        if window:
            wm.progress_update(int(1000 * fraction))
        if printer is not None:
            printer(Progress(phase="working", message=stage, prepared=fraction))

    if window:
        wm.progress_begin(0, 1000)
    try:
        yield report
    finally:
        if window:
            wm.progress_end()


def tag_redraw(kinds=("STATUSBAR", "VIEW_3D")) -> None:
    """Redraw the areas of these types; of a 3D view only its main region (its header, tool
    bar and sidebar are as many more draws, each costly in software OpenGL)."""
    wm = getattr(bpy.context, "window_manager", None)
    for window in getattr(wm, "windows", ()):
        for area in window.screen.areas:
            if area.type not in kinds:
                continue
            if area.type != "VIEW_3D":
                area.tag_redraw()
                continue
            for region in area.regions:
                if region.type == "WINDOW":
                    region.tag_redraw()


def draw_status(self, context) -> None:
    """Prepended to the status bar: a progress bar, the status line and a stop button per job."""
    for running in list(RUNNING.values()):
        p = running.progress
        row = self.layout.row(align=True)
        bar = row.row(align=True)
        bar.ui_units_x = 6
        bar.progress(factor=p.fraction, type="BAR",
                     text=(f"{running.title} {p.step:,}" if p.until_done else
                           f"{running.title} {100 * p.fraction:.0f} %"))
        row.label(text=status_line(p, running.title))
        stop = row.operator(SPLAT_OT_train_stop.bl_idname, text="", icon="CANCEL", emboss=False)
        stop.key = running.key
        self.layout.separator()


def ensure_status_draw() -> None:
    """Keep `draw_status` in the status bar: `WorkSpace.status_text_set` (used by some Python
    modal tools) swaps the header's draw function and may restore one without it."""
    header = bpy.types.STATUSBAR_HT_header
    funcs = getattr(header.draw, "_draw_funcs", None)
    if funcs is not None:
        if draw_status not in funcs:
            funcs.insert(0, draw_status)
    elif getattr(header, "_draw_orig", header.draw) is header.draw:
        header.prepend(draw_status)


def _can_write(context, obj) -> bool:
    """Not while a render locks the interface, nor into an object in Edit Mode (the edit mesh
    would overwrite it). A deleted object is no obstacle: a new one is made."""
    if getattr(context.window_manager, "is_interface_locked", False):
        return False
    try:
        return obj is None or obj.mode != "EDIT"
    except ReferenceError:
        return True


def draw_settings(layout, operator, groups) -> None:
    """An operator's settings dialog: each group (a tuple of property names) in an aligned
    column, a lone name on its own row."""
    layout.use_property_split = True
    layout.use_property_decorate = False
    for group in groups:
        if isinstance(group, str):
            layout.prop(operator, group)
            continue
        column = layout.column(align=True)
        for name in group:
            column.prop(operator, name)


class JobOperator:
    """Mixin for an operator that runs an `OperatorJob` (see the module docstring)."""

    interactive: BoolProperty(default=False, options={"HIDDEN", "SKIP_SAVE"},
                              description="Run in the background from a modal timer (set by "
                                          "invoke; scripts get a blocking run)")

    _timer = None
    _key = ""

    def invoke_settings(self, context, title: str, confirm_text: str) -> set:
        """`invoke` for a job with a settings dialog: the dialog's OK runs `execute` in the
        background; without a window `execute` blocks at once."""
        self.interactive = wants_background(context)
        if not self.interactive:
            return self.execute(context)
        return context.window_manager.invoke_props_dialog(self, width=420, title=title,
                                                          confirm_text=confirm_text)

    def invoke_file_browser(self, context, event=None) -> set:
        """`invoke` for a job that starts from the file browser (an importer): its accept runs
        `execute` in the background."""
        self.interactive = wants_background(context)
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def job_threads(self, context, override: int = 0) -> int:
        """Threads for the job's native work (`blender/threads.py`): `override` (the operator's
        own Threads) or the scene's setting; every core but one at most when the job will run
        in the background beside the UI."""
        return scene_threads(context.scene, override=override,
                             beside_ui=getattr(self, "interactive", False)
                             and wants_background(context))

    def run_job(self, context, job: OperatorJob) -> set:
        """The one execute path: in the background when `self.interactive` and there is a
        window, else blocking."""
        if job.key in RUNNING:
            name = job.key.split(":", 1)[-1]
            self.report({"ERROR"}, f"{job.title}: '{name}' is already running")
            return {"CANCELLED"}
        if getattr(self, "interactive", False) and wants_background(context):
            return self._start_background(context, job)
        wm = context.window_manager
        window = wants_background(context)
        printer = ProgressPrinter(job.title) if bpy.app.background else None

        def on_progress(p: Progress) -> None:
            if printer is not None and p.phase != "failed":  # `finish` reports it, once
                printer(p)
            if window:
                wm.progress_update(int(1000 * p.fraction))

        job.job.on_progress = on_progress  # the runner owns a blocking job's progress
        if window:
            wm.progress_begin(0, 1000)
        try:
            job.job.run(raise_errors=False)  # errors are reported by `finish`
        finally:
            if window:
                wm.progress_end()
        return self._report_end(context, *job.finish(job, True))

    def _report_end(self, context, level: str, message: str, obj) -> set:
        if obj is not None:
            make_active(context, obj)
        self.report({level}, message)  # headless, Blender prints reports to the terminal
        return {"CANCELLED"} if level == "ERROR" else {"FINISHED"}

    def _start_background(self, context, job: OperatorJob) -> set:
        if job.apply is not None:  # it will add splats: see `hooks.make_helper_ahead`
            hooks.make_helper_ahead(context.scene)
        RUNNING[job.key] = job
        self._key = job.key
        job.job.start()
        wm = context.window_manager
        self._timer = wm.event_timer_add(TIMER_STEP, window=context.window)
        wm.modal_handler_add(self)
        ensure_status_draw()
        tag_redraw(("STATUSBAR",))
        return {"RUNNING_MODAL"}

    def _stop_timer(self, context) -> None:
        if self._timer is not None:
            try:
                context.window_manager.event_timer_remove(self._timer)
            except (ReferenceError, ValueError, RuntimeError):
                pass
            self._timer = None

    def _show(self, context, running: OperatorJob) -> None:
        snapshot = running.job.take_snapshot() or running.pending
        running.pending = None
        if snapshot is None or running.apply is None:
            return
        if not _can_write(context, running.target()) or time.monotonic() < running.next_show():
            running.pending = snapshot
            return
        start = time.monotonic()
        made = running.target() is None
        running.apply(*snapshot)
        hooks.bridge_new_splats(running.target())
        if made and isinstance(running.job, TrainingJob):
            running.job.hold(NEW_OBJECT_HOLD)
        running.shown_at = time.monotonic()
        running.write_cost = running.shown_at - start
        running.probe = StallProbe(COST_WINDOW)

    def modal(self, context, event):
        running = RUNNING.get(self._key)
        if running is None:
            self._stop_timer(context)
            return {"CANCELLED"}
        if event.type == "ESC" and event.value == "PRESS":
            if not running.job.cancelled:
                running.job.cancel()
                self.report({"INFO"}, f"{running.title}: stopping after the current step")
            return {"RUNNING_MODAL"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        try:
            running.job.poll(STAGE_BUDGET)
            running.progress = running.job.progress()
            if running.job.done:
                return self._end(context, running)
            self._show(context, running)
        except Exception as error:  # never leave a job without its modal handler
            running.job.cancel()
            running.job.join(30.0)
            self._end(context, running)
            self.report({"ERROR"}, f"{running.title}: {error}")
            return {"CANCELLED"}
        ensure_status_draw()
        # The status bar only: a 3D view redraw costs far more (see SHOW_INTERVAL); a job's
        # `apply` redraws the view when it shows a snapshot.
        tag_redraw(("STATUSBAR",))
        return {"PASS_THROUGH"}

    def _end(self, context, running: OperatorJob) -> set:
        self._stop_timer(context)
        RUNNING.pop(running.key, None)
        running.pending = None
        try:
            write = _can_write(context, running.target())
            if not write:
                self.report({"WARNING"}, f"{running.title}: the object is in Edit Mode or the "
                                         f"interface is locked: not updated")
            level, message, obj = running.finish(running, write)
            if running.apply is not None:
                hooks.bridge_new_splats(obj)
        finally:
            tag_redraw()
        return self._report_end(context, level, message, obj)

    def cancel(self, context) -> None:
        """Blender ends the operator (another file loads, the window closes): stop the job (a
        training job saves its checkpoint). Blender data is not touched here."""
        self._stop_timer(context)
        running = RUNNING.pop(self._key, None)
        if running is not None:
            running.job.cancel()
            running.job.join(30.0)


def stop_all(timeout: float = 30.0) -> None:
    """Stop every background job (training jobs save their checkpoints)."""
    for running in list(RUNNING.values()):
        running.job.cancel()
    for running in list(RUNNING.values()):
        running.job.join(timeout)


class SPLAT_OT_train_stop(bpy.types.Operator):
    """Stop a background job (training, baking to splats, mesh conversion) after its current
    step, keeping the last state (training saves a checkpoint)"""

    bl_idname = "splat.train_stop"  # the name scripts know from when only training ran here
    bl_label = "Stop Job"

    key: StringProperty(options={"HIDDEN", "SKIP_SAVE"},
                        description="The job to stop (empty: all)")

    @classmethod
    def poll(cls, context):
        return bool(RUNNING)

    def execute(self, context):
        stopped = [r for k, r in RUNNING.items() if not self.key or k == self.key]
        for running in stopped:
            running.job.cancel()
        self.report({"INFO"}, f"stopping {len(stopped)} job(s) after the current step")
        return {"FINISHED"}


def menu_parent():
    """Where job operators go: the 3D View's Gaussian Splats submenu when the edit operators
    made one, else Object."""
    return getattr(bpy.types, "VIEW3D_MT_splat", None) or bpy.types.VIEW3D_MT_object


@bpy.app.handlers.persistent
def _on_load_pre(*_args) -> None:
    stop_all()
    RUNNING.clear()


CLASSES = (SPLAT_OT_train_stop,)


def register() -> None:
    register_classes(CLASSES)
    bpy.types.STATUSBAR_HT_header.remove(draw_status)
    ensure_status_draw()
    if _on_load_pre not in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.append(_on_load_pre)


def unregister() -> None:
    stop_all()
    RUNNING.clear()
    if _on_load_pre in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.remove(_on_load_pre)
    bpy.types.STATUSBAR_HT_header.remove(draw_status)
    unregister_classes(CLASSES)
