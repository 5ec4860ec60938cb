"""Training Gaussians in Blender: `bpy.ops.splat.train` on an imported COLMAP scene, and
`train_colmap_collection()` for scripts.

    bpy.ops.splat.train(collection="garden", steps=7000, max_gaussians=200_000)   # blocks
    bpy.ops.splat.train("INVOKE_DEFAULT")      # the menu's way: a dialog, then in the background

    from addon.blender.train_operator import train_colmap_collection
    obj = train_colmap_collection(bpy.data.collections["garden"], TrainConfig(steps=3000))

Which scene: the COLMAP collection made by `splat.import_colmap` (it carries
`colmap_transform`, the model folder and the image folder), found from the `collection`
property, else the active object's collection, else the active collection in the outliner,
else the only COLMAP collection in the scene. The photos are read again from the model and image
folder the collection names (or `image_folder`, e.g. a downscaled `images_4`), and mapped by the
collection's `colmap_transform` into exactly the frame the import placed the cameras in, so the
splats line up with the imported cameras. If the camera objects have since been moved together
(parented, transformed as a rig) the splat object gets that same similarity as its transform;
cameras moved one by one leave it at the import's frame (the report says so).

The splat object: `<collection> Splats` in the collection (the collection's `splat_object`
property points at it), created on the first update and rewritten on every later one and on
every later training of the same collection. Its `splat_trained_steps` (and, when the held-out
views were evaluated, `splat_heldout_psnr` / `splat_heldout_ssim`) say what it holds.

Two ways to run:
- Blocking (`execute`; scripts, `blender --background`, the bpy wheel): returns when done; the
  object holds the result. In background mode a status line is printed every `update_every`
  steps.
- In the background (`invoke`, from the menu: a settings dialog, then `interactive`): the
  trainer runs on a worker thread (the native kernels release the GIL, so Blender stays
  responsive) and a modal handler polls it from a 0.25 s timer on the main thread (bpy is not
  thread-safe: only the main thread touches Blender data). The status bar shows a progress bar
  and "Training step/total | loss | PSNR | Gaussians | ms/step | ETA" with a stop button; every
  `update_every` steps the Gaussians are written into the splat object so it forms in the
  viewport (skipped while the object is in Edit Mode or a render locks the interface). Esc (or
  the stop button, or Object > Gaussian Splats > Stop Training) stops after the current step:
  the object gets the last state and the checkpoint is saved. Loading another file or
  disabling the add-on stops it too (the checkpoint is still saved). Right-click does not stop
  it: the user keeps working meanwhile. The dialog's OK calls `execute`, which adds the timer
  and the modal handler and returns RUNNING_MODAL (as Blender's "Operator Modal Timer"
  template does). No redo panel (bl_options has no REGISTER): redoing would train again.

`wm.progress_begin/update` (which turns the mouse cursor into a counter) is used only by the
blocking path with a window, not while the user keeps working during background training.

Checkpoints hold the whole optimiser state (`Trainer.save_checkpoint`). Saved every
`checkpoint_every` steps and at the end (also when stopped), at `checkpoint` or by default in
`<blend name>_splats/<collection>.npz` beside the saved .blend, or, for an unsaved file, in the
user cache folder (`~/.cache/gaussian-splatting/checkpoints` on Linux). The path used is kept on
the collection (`splat_checkpoint`), so `resume` finds it even after the .blend is saved
elsewhere. `resume=True` continues from it up to `steps` total steps (the budget and threads
may change; the SH degree is the checkpoint's).
"""

from __future__ import annotations

import hashlib
import os
import re
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import bpy
import numpy as np
from bpy.props import BoolProperty, FloatProperty, IntProperty, StringProperty

from ..core import colmap
from ..core.cameras import CAMERA_AXIS_FLIP
from ..core.dataset import ColmapDataset
from ..core.gaussians import Gaussians
from ..core.jobs import Progress, TrainingJob, status_line
from ..core.train import Trainer, TrainConfig
from . import splat_object
from .camera_adapter import to_matrix
from .registration import register_classes, unregister_classes

COLMAP_KEY = "colmap_transform"
OBJECT_KEY = "splat_object"
CHECKPOINT_KEY = "splat_checkpoint"


# -- the COLMAP collection ------------------------------------------------------------------------

def is_colmap_collection(collection) -> bool:
    return collection is not None and COLMAP_KEY in collection and "colmap_model_dir" in collection


def colmap_collections(scene=None) -> list:
    """COLMAP collections linked into `scene` (default: all in the file)."""
    pool = scene.collection.children_recursive if scene is not None else bpy.data.collections
    return [c for c in pool if is_colmap_collection(c)]


def find_colmap_collection(context, name: str = ""):
    """The COLMAP collection to train: by `name`, else the active object's, else the active
    outliner collection, else the scene's only one. None when there is none (or no clear one)."""
    if name:
        collection = bpy.data.collections.get(name)
        return collection if is_colmap_collection(collection) else None
    obj = getattr(context, "active_object", None)
    if obj is not None:
        for collection in obj.users_collection:
            if is_colmap_collection(collection):
                return collection
    layer = getattr(getattr(context, "view_layer", None), "active_layer_collection", None)
    if layer is not None and is_colmap_collection(layer.collection):
        return layer.collection
    scene = getattr(context, "scene", None)
    found = colmap_collections(scene) if scene is not None else []
    return found[0] if len(found) == 1 else None


def _absolute(path) -> str:
    """A stored folder as an absolute path (Blender's // prefix and relative paths resolved)."""
    path = str(path or "")
    return str(Path(bpy.path.abspath(path)).absolute()) if path else ""


@dataclass
class ColmapSource:
    """What training needs from a COLMAP collection, read on the main thread (plain values the
    worker thread can use)."""

    name: str
    model_dir: str
    image_folder: str  # absolute image folder of the import, or the folder name
    cache_dir: str | None  # the root the import's undistortion cache lives in
    transform: np.ndarray  # (4, 4) COLMAP frame -> the import's frame (Blender world)

    @classmethod
    def of(cls, collection) -> "ColmapSource":
        if not is_colmap_collection(collection):
            raise ValueError(f"collection {collection.name!r} is not an imported COLMAP scene")
        undistorted = _absolute(collection.get("colmap_undistorted_dir", ""))
        folder = _absolute(collection.get("colmap_image_dir", "")) or \
            str(collection.get("colmap_image_folder", "images"))
        transform = np.array(collection[COLMAP_KEY], np.float64).reshape(4, 4)
        return cls(collection.name, _absolute(collection["colmap_model_dir"]), folder,
                   str(Path(undistorted).parent) if undistorted else None, transform)

    def dataset(self, image_folder: str = "", *, downscale: float = 1.0, test_every: int = 8,
                preload_threads: int = 0, progress=None) -> ColmapDataset:
        """The training dataset in the import's frame (Blender-free; runs on the worker).
        `image_folder` overrides the import's (a name beside the model or an absolute path).
        Photos are decoded now on `preload_threads` threads (0: every core; -1: lazily, on
        first use). `progress(fraction, message)` may raise to cancel."""
        report = progress or (lambda fraction, message: None)
        scene = colmap.read_colmap(self.model_dir, image_folder or self.image_folder,
                                   cache_dir=self.cache_dir, align=False,
                                   progress=lambda f, m: report(0.3 * f, m))
        scene = scene.transformed(self.transform)
        data = ColmapDataset(scene, downscale=downscale, test_every=test_every)
        if preload_threads >= 0:  # in batches, so that a cancel is seen between them
            workers = preload_threads or os.cpu_count() or 1
            with ThreadPoolExecutor(max_workers=workers) as pool:
                for start in range(0, len(data), 4 * workers):
                    batch = range(start, min(start + 4 * workers, len(data)))
                    report(0.3 + 0.7 * start / len(data),
                           f"decoding photos {start + 1}-{batch[-1] + 1} of {len(data)}")
                    list(pool.map(data.pixels, batch))
        report(1.0, f"{len(data)} photos ready")
        return data


def _safe_name(name: str) -> str:
    return re.sub(r"[^\w.-]+", "_", name).strip("_") or "scene"


def default_checkpoint(collection) -> Path:
    """`<blend>_splats/<collection>.npz` beside the saved .blend, else the user cache folder."""
    name = _safe_name(collection.name)
    if bpy.data.filepath:
        blend = Path(bpy.path.abspath(bpy.data.filepath))
        return blend.parent / f"{blend.stem}_splats" / f"{name}.npz"
    key = hashlib.sha1(str(collection.get("colmap_model_dir", "")).encode()).hexdigest()[:8]
    return colmap.user_cache_dir().parent / "checkpoints" / f"{name}-{key}.npz"


def checkpoint_path(collection, explicit: str = "", *, resume: bool = False) -> Path:
    if explicit:
        return Path(bpy.path.abspath(explicit))
    stored = str(collection.get(CHECKPOINT_KEY, "") or "")
    if resume and stored and Path(stored).is_file():
        return Path(stored)
    return default_checkpoint(collection)


# -- placing the splats ---------------------------------------------------------------------------

def _similarity_fit(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Least-squares similarity (Umeyama) with dst ~ s R src + t, as a 4x4."""
    mu_s, mu_d = src.mean(0), dst.mean(0)
    a, b = src - mu_s, dst - mu_d
    var = (a * a).sum() / len(src)
    u, d, vt = np.linalg.svd(b.T @ a / len(src))
    fix = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        fix[2, 2] = -1
    rotation = u @ fix @ vt
    scale = float((d * np.diag(fix)).sum() / var) if var > 0 else 1.0
    m = np.eye(4)
    m[:3, :3] = scale * rotation
    m[:3, 3] = mu_d - scale * rotation @ mu_s
    return m


def rig_transform(collection, dataset) -> tuple[np.ndarray, str | None]:
    """The world matrix for splats trained in the import's frame, so that they sit where the
    collection's camera objects now see: identity while the cameras are where the import put
    them; the common similarity when they have been moved together; identity and a warning when
    they disagree. Compares camera centres and orientations (the axes' lengths, which Blender
    ignores for the view, are ignored here too)."""
    index = {name: i for i, name in enumerate(getattr(dataset, "names", []))}
    expected, actual = [], []
    if collection is not None:
        for obj in collection.all_objects:
            i = index.get(obj.get("colmap_image_name")) if obj.type == "CAMERA" else None
            if i is None:
                continue
            e = dataset.cameras[i].camera_to_world @ CAMERA_AXIS_FLIP
            m = np.array(obj.matrix_world, np.float64)
            lengths = np.linalg.norm(m[:3, :3], axis=0)
            if not (lengths > 0).all():
                continue
            m[:3, :3] /= lengths
            expected.append(e)
            actual.append(m)
    if not expected:
        return np.eye(4), None
    src = np.array([e[:3, 3] for e in expected])
    dst = np.array([m[:3, 3] for m in actual])
    size = max(float(np.linalg.norm(src - src.mean(0), axis=1).max()), 1e-9)
    if len(expected) >= 3 and np.linalg.matrix_rank(src - src.mean(0), tol=1e-6 * size) >= 2:
        fit = _similarity_fit(src, dst)
    else:
        fit = actual[0] @ np.linalg.inv(expected[0])
    scale = float(np.cbrt(abs(np.linalg.det(fit[:3, :3]))))
    rotation = fit[:3, :3] / scale
    moved = src @ fit[:3, :3].T + fit[:3, 3]
    position_error = float(np.linalg.norm(moved - dst, axis=1).max()) / (scale * size)
    angle_error = max(
        float(np.degrees(np.arccos(np.clip((np.trace((rotation @ e[:3, :3]).T @ m[:3, :3]) - 1) / 2,
                                           -1.0, 1.0))))
        for e, m in zip(expected, actual))
    if position_error > 1e-3 or angle_error > 0.1:
        return np.eye(4), (f"the cameras of {collection.name!r} were moved one by one since the "
                           f"import: the splats are placed in the import's frame")
    if np.abs(fit - np.eye(4)).max() <= 1e-5 * max(1.0, size):
        return np.eye(4), None
    return fit, None


def replace_gaussians(obj, gaussians: Gaussians) -> None:
    """Rewrite a splat object's mesh with `gaussians` (any count; the mesh is kept)."""
    bad = gaussians.non_finite()
    if bad is not None:
        raise ValueError(f"Gaussians.{bad} holds NaN or Inf")
    mesh = obj.data
    if len(mesh.vertices) != len(gaussians):
        mesh.clear_geometry()
        mesh.vertices.add(len(gaussians))
    splat_object.write_gaussians(mesh, gaussians)
    settings = obj.splat
    if settings.sh_degree > gaussians.degree or not settings.is_splat:
        settings.sh_degree = gaussians.degree
    settings.is_splat = True


def _alive(obj):
    try:
        return obj if obj is not None and obj.name is not None else None
    except ReferenceError:
        return None


def write_splats(collection_name: str, gaussians: Gaussians, *, dataset=None,
                 antialiased: bool = False, step: int | None = None) -> tuple[object, str | None]:
    """Write `gaussians` into the collection's splat object, creating it (placed by
    `rig_transform`) when there is none. Returns (object, warning or None). Main thread only."""
    collection = bpy.data.collections.get(collection_name)
    obj = _alive(collection.get(OBJECT_KEY)) if collection is not None else None
    warning = None
    if obj is not None and splat_object.is_splat_object(obj) and obj.users:
        replace_gaussians(obj, gaussians)
    else:
        target = collection if collection is not None else bpy.context.scene.collection
        obj = splat_object.create_splat_object(
            gaussians, f"{collection_name} Splats", collection=target, antialiased=antialiased,
            sh_degree=gaussians.degree)
        if dataset is not None:
            world, warning = rig_transform(collection, dataset)
            obj.matrix_world = to_matrix(world)
        if collection is not None:
            collection[OBJECT_KEY] = obj
    if step is not None:
        obj["splat_trained_steps"] = int(step)
    return obj, warning


def _make_active(context, obj) -> None:
    layer = getattr(context, "view_layer", None)
    if layer is None:
        return
    try:
        obj.select_set(True, view_layer=layer)  # RuntimeError: not in this view layer
    except RuntimeError:
        return
    for other in context.selected_objects:
        if other != obj:
            other.select_set(False)
    layer.objects.active = obj


# -- jobs shared with the bake operator ---------------------------------------------------------

@dataclass
class Running:
    """A job running in the background, as the modal handler and the status bar see it."""

    key: str
    title: str
    job: TrainingJob
    apply: Callable[[int, Gaussians], None]  # main thread: show a snapshot
    # main thread, at the end: write the final state (when `write`), return (level, message)
    finish: Callable[["Running", bool], tuple[str, str]]
    progress: Progress
    target: Callable[[], object] = lambda: None  # the object snapshots go into (or None)
    pending: tuple[int, Gaussians] | None = None
    last_applied: int = -1


RUNNING: dict[str, Running] = {}
TIMER_STEP = 0.25


def _tag_redraw(kinds=("STATUSBAR", "VIEW_3D")) -> None:
    wm = getattr(bpy.context, "window_manager", None)
    for window in getattr(wm, "windows", ()):
        for area in window.screen.areas:
            if area.type in kinds:
                area.tag_redraw()


def draw_status(self, context) -> None:
    """Prepended to the status bar: a progress bar, the status line and a stop button per job."""
    for running in list(RUNNING.values()):
        p = running.progress
        row = self.layout.row(align=True)
        bar = row.row(align=True)
        bar.ui_units_x = 6
        bar.progress(factor=p.fraction, type="BAR",
                     text=f"{running.title} {100 * p.fraction:.0f} %")
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


class JobModal:
    """Mixin: run a `Running` record in the background from a timer (see the module docstring)."""

    _timer = None
    _key = ""

    def start_background(self, context, running: Running) -> set:
        RUNNING[running.key] = running
        self._key = running.key
        running.job.start()
        wm = context.window_manager
        self._timer = wm.event_timer_add(TIMER_STEP, window=context.window)
        wm.modal_handler_add(self)
        ensure_status_draw()
        _tag_redraw(("STATUSBAR",))
        return {"RUNNING_MODAL"}

    def _stop_timer(self, context) -> None:
        if self._timer is not None:
            try:
                context.window_manager.event_timer_remove(self._timer)
            except (ReferenceError, ValueError, RuntimeError):
                pass
            self._timer = None

    def _show(self, context, running: Running) -> None:
        snapshot = running.job.take_snapshot() or running.pending
        running.pending = None
        if snapshot is None:
            return
        if not _can_write(context, running.target()):
            running.pending = snapshot
            return
        running.apply(*snapshot)
        running.last_applied = snapshot[0]

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
        running.progress = running.job.progress()
        try:
            if running.job.done:
                return self._end(context, running)
            self._show(context, running)
        except Exception as error:  # never leave a worker without its modal handler
            running.job.cancel()
            running.job.join(30.0)
            self._end(context, running)
            self.report({"ERROR"}, f"{running.title}: {error}")
            return {"CANCELLED"}
        ensure_status_draw()
        _tag_redraw()
        return {"PASS_THROUGH"}

    def _end(self, context, running: Running) -> set:
        self._stop_timer(context)
        RUNNING.pop(running.key, None)
        running.pending = None
        try:
            write = _can_write(context, running.target())
            if not write:
                self.report({"WARNING"}, f"{running.title}: the object is in Edit Mode or the "
                                         f"interface is locked: not updated")
            level, message = running.finish(running, write)
        finally:
            _tag_redraw()
        self.report({level}, message)
        return {"CANCELLED"} if level == "ERROR" else {"FINISHED"}

    def cancel(self, context) -> None:
        """Blender ends the operator (another file loads, the window closes): stop the worker;
        it saves its checkpoint. Blender data is not touched here."""
        self._stop_timer(context)
        running = RUNNING.pop(self._key, None)
        if running is not None:
            running.job.cancel()
            running.job.join(30.0)


def stop_all(timeout: float = 30.0) -> None:
    """Stop every background job (each saves its checkpoint)."""
    for running in list(RUNNING.values()):
        running.job.cancel()
    for running in list(RUNNING.values()):
        running.job.join(timeout)


# -- training a collection ------------------------------------------------------------------------

@dataclass
class TrainRequest:
    source: ColmapSource
    config: TrainConfig
    checkpoint: Path
    resume: bool = False
    image_folder: str = ""
    downscale: float = 1.0
    test_every: int = 8
    checkpoint_every: int = 1000
    update_every: int = 200
    compact: bool = False

    def make_trainer(self, job: TrainingJob | None = None) -> Trainer:
        """Load the photos and make (or resume) the trainer. Blender-free: runs on the worker;
        `job.loading` reports (and stops a cancelled job between batches of photos)."""
        threads = self.config.threads
        dataset = self.source.dataset(self.image_folder, downscale=self.downscale,
                                      test_every=self.test_every, preload_threads=threads,
                                      progress=job.loading if job is not None else None)
        if self.resume:
            trainer = Trainer.load_checkpoint(self.checkpoint, dataset)
            trainer.config.threads = threads
            trainer.config.max_gaussians = self.config.max_gaussians
        else:
            trainer = Trainer(dataset, self.config)
        return trainer

    def job(self, on_progress=None) -> TrainingJob:
        return TrainingJob(self.make_trainer, steps=self.config.steps, checkpoint=self.checkpoint,
                           checkpoint_every=self.checkpoint_every,
                           snapshot_every=self.update_every, compact_after=self.compact,
                           on_progress=on_progress)


def train_request(collection, config: TrainConfig | None = None, *, image_folder: str = "",
                  downscale: float = 1.0, test_every: int = 8, checkpoint: str | Path = "",
                  resume: bool = False, checkpoint_every: int = 1000, update_every: int = 200,
                  compact: bool = False) -> TrainRequest:
    """Check the inputs on the main thread; raises ValueError / FileNotFoundError."""
    source = ColmapSource.of(collection)
    path = checkpoint_path(collection, str(checkpoint), resume=resume)
    if resume and not path.is_file():
        raise FileNotFoundError(f"no checkpoint to resume at {path}")
    if not downscale >= 1.0:
        raise ValueError(f"downscale must be at least 1, got {downscale}")
    return TrainRequest(source, config or TrainConfig(), path, resume, image_folder, downscale,
                        test_every, checkpoint_every, update_every, compact)


def finish_training(request: TrainRequest, job: TrainingJob, *,
                    write: bool = True) -> tuple[str, str, object]:
    """Main thread, after the job: the object gets the final Gaussians (unless not `write`),
    the collection the checkpoint path. Returns (level, message, object or None)."""
    snapshot = job.final
    obj = None
    warning = None
    trainer = job.trainer
    if snapshot is not None and trainer is not None and write:
        obj, warning = write_splats(request.source.name, snapshot[1], dataset=trainer.dataset,
                                    antialiased=trainer.config.antialiased, step=snapshot[0])
    elif trainer is not None:
        collection = bpy.data.collections.get(request.source.name)
        obj = _alive(collection.get(OBJECT_KEY)) if collection is not None else None
    return _finish_message(request, job, obj, warning)


def _finish_message(request: TrainRequest, job: TrainingJob, obj,
                    warning) -> tuple[str, str, object]:
    collection = bpy.data.collections.get(request.source.name)
    if collection is not None and job.checkpoint_saved:
        collection[CHECKPOINT_KEY] = str(request.checkpoint)
    p = job.progress()
    if job.error is None and job.trainer is None:
        return "INFO", "Training cancelled while loading the photos: nothing changed", obj
    if job.error is not None:
        first = str(job.error).splitlines()[0] if str(job.error) else type(job.error).__name__
        if job.trainer is None:
            return "ERROR", f"Training could not start: {first}", obj
        return "ERROR", f"Training failed at step {p.step}: {first}", obj
    if obj is not None and p.evaluation is not None and p.evaluation.views:
        obj["splat_heldout_psnr"] = p.evaluation.psnr
        obj["splat_heldout_ssim"] = p.evaluation.ssim
    name = f"'{obj.name}'" if obj is not None else "the splat object"
    where = f"; checkpoint {request.checkpoint}" if job.checkpoint_saved else ""
    if p.phase == "cancelled":
        message = (f"Training stopped at step {p.step:,} of {p.total:,}: {name} has "
                   f"{p.gaussians:,} Gaussians{where} (train again with Resume to continue)")
    else:
        quality = ""
        if p.evaluation is not None and p.evaluation.views:
            quality = (f", held-out PSNR {p.evaluation.psnr:.2f} dB / SSIM "
                       f"{p.evaluation.ssim:.3f} on {p.evaluation.views} views")
        steps = (f"{p.step:,} steps" if not p.start_step else
                 f"from step {p.start_step:,} to {p.step:,}")
        message = (f"Trained {steps} in {p.elapsed:.1f} s: {name} has "
                   f"{p.gaussians:,} Gaussians{quality}{compaction_note(job)}{where}")
    if warning:
        return "WARNING", f"{message} ({warning})", obj
    return "INFO", message, obj


def background_training(request: TrainRequest) -> Running:
    """The record the modal handler polls: the job (not started) and what the main thread does
    with its snapshots and its end."""
    job = request.job()
    name = request.source.name

    def target():
        collection = bpy.data.collections.get(name)
        return _alive(collection.get(OBJECT_KEY)) if collection is not None else None

    def apply(step, gaussians):
        write_splats(name, gaussians, dataset=job.trainer.dataset,
                     antialiased=request.config.antialiased, step=step)

    def finish(running, write):
        level, message, obj = finish_training(request, running.job, write=write)
        if obj is not None:
            _make_active(bpy.context, obj)
        return level, message

    return Running(f"train:{name}", "Training", job, apply, finish, job.progress(), target)


def compaction_note(job: TrainingJob) -> str:
    report = job.compaction
    if report is None:
        return ""
    b, a = report.before, report.after
    return (f"; compacted {b['gaussians']:,} -> {a['gaussians']:,} Gaussians, SH degree "
            f"{b['sh_degree']} -> {a['sh_degree']}, training-view PSNR {b['psnr']:.2f} -> "
            f"{a['psnr']:.2f} dB")


def _printer(title: str, every: int):
    state = {"phase": None}

    def on_progress(p: Progress) -> None:
        if p.phase != state["phase"] or (p.phase == "training" and every and p.step % every == 0):
            state["phase"] = p.phase
            print(status_line(p, title), flush=True)

    return on_progress


def train_colmap_collection(collection, config: TrainConfig | None = None,
                            progress: Callable[[Progress], None] | None = None, **options):
    """Train on an imported COLMAP collection on the calling thread; returns the splat object
    (created or updated). `progress(Progress)` is called after every step. `options`: those of
    `train_request` (image_folder, downscale, test_every, checkpoint, resume, checkpoint_every,
    update_every, compact). Raises on bad input or a failure."""
    request = train_request(collection, config, **options)
    job = request.job(progress)
    job.run()
    level, message, obj = finish_training(request, job)
    return obj


# -- operators ------------------------------------------------------------------------------------

class SPLAT_OT_train(JobModal, bpy.types.Operator):
    """Train Gaussians on the CPU from the photos of an imported COLMAP scene. From the menu it
    runs in the background (Esc stops it, keeping the last state); from scripts it blocks"""

    bl_idname = "splat.train"
    bl_label = "Train Gaussians"
    bl_options = {"UNDO"}  # no redo panel: redoing would train again

    collection: StringProperty(
        name="COLMAP Scene",
        description="The imported COLMAP collection (empty: the active object's, the active "
                    "collection, or the scene's only one)")
    steps: IntProperty(name="Steps", default=7000, min=1, soft_max=30000,
                       description="Total optimisation steps (when resuming: up to this many)")
    max_gaussians: IntProperty(name="Max Gaussians", default=300_000, min=1,
                               soft_max=3_000_000, description="The Gaussian budget")
    sh_degree: IntProperty(name="SH Degree", default=3, min=0, max=3,
                           description="Spherical-harmonics bands to train (view-dependent colour)")
    image_folder: StringProperty(
        name="Image Folder",
        description="Photos to train on: a folder beside the model (images_2, images_4, ...) or "
                    "an absolute path (empty: the import's)")
    downscale: FloatProperty(name="Downscale", default=1.0, min=1.0, soft_max=8.0,
                             description="Divide the photos' size by this (faster, coarser)")
    hold_out: IntProperty(name="Hold Out Every", default=8, min=0, soft_max=32,
                          description="Every n-th photo (by name) is a held-out test view "
                                      "(0: train on all)")
    seed: IntProperty(name="Seed", default=0, min=0)
    threads: IntProperty(name="Threads", default=0, min=0, soft_max=64,
                         description="Worker threads for the kernels (0: every core)")
    antialiased: BoolProperty(name="Antialiased", default=False,
                              description="Train for the Mip-Splatting antialiased render mode")
    update_every: IntProperty(name="Update Every", default=200, min=0, soft_max=2000,
                              description="Steps between updates of the splat object while "
                                          "training in the background (0: only at the end)")
    checkpoint_every: IntProperty(name="Checkpoint Every", default=1000, min=0, soft_max=10000,
                                  description="Steps between checkpoints (0: only at the end)")
    compact: BoolProperty(name="Compact", default=False,
                          description="After training, prune negligible Gaussians and unneeded "
                                      "SH bands")
    resume: BoolProperty(name="Resume", default=False,
                         description="Continue from the checkpoint (up to Steps in total)")
    checkpoint: StringProperty(name="Checkpoint", subtype="FILE_PATH",
                               description="Checkpoint file (empty: beside the .blend, or the "
                                           "user cache folder for an unsaved file)")
    interactive: BoolProperty(default=False, options={"HIDDEN", "SKIP_SAVE"},
                              description="Train on a worker thread with a modal timer (set by "
                                          "invoke; scripts get a blocking run)")

    @classmethod
    def poll(cls, context):
        return any(is_colmap_collection(c) for c in bpy.data.collections)

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        layout.prop(self, "collection")
        col = layout.column(align=True)
        col.prop(self, "steps")
        col.prop(self, "max_gaussians")
        col.prop(self, "sh_degree")
        col = layout.column(align=True)
        col.prop(self, "image_folder")
        col.prop(self, "downscale")
        col.prop(self, "hold_out")
        col = layout.column(align=True)
        col.prop(self, "update_every")
        col.prop(self, "checkpoint_every")
        col.prop(self, "threads")
        col.prop(self, "seed")
        layout.prop(self, "antialiased")
        layout.prop(self, "compact")
        layout.prop(self, "resume")
        layout.prop(self, "checkpoint")

    def invoke(self, context, event):
        collection = find_colmap_collection(context, self.collection)
        if collection is not None:
            self.collection = collection.name
        self.interactive = not bpy.app.background and context.window is not None
        if not self.interactive:
            return self.execute(context)
        return context.window_manager.invoke_props_dialog(self, width=420, title="Train Gaussians",
                                                          confirm_text="Train")

    def execute(self, context):
        collection = find_colmap_collection(context, self.collection)
        if collection is None:
            self.report({"ERROR"}, f"no COLMAP collection named {self.collection!r}" if
                        self.collection else "no COLMAP scene to train: import one (File > "
                        "Import > COLMAP Scene) and select one of its cameras")
            return {"CANCELLED"}
        self.collection = collection.name
        if f"train:{collection.name}" in RUNNING:
            self.report({"ERROR"}, f"'{collection.name}' is already training")
            return {"CANCELLED"}
        config = TrainConfig(steps=self.steps, max_gaussians=self.max_gaussians,
                             sh_degree=self.sh_degree, seed=self.seed, threads=self.threads,
                             antialiased=self.antialiased)
        try:
            request = train_request(collection, config, image_folder=self.image_folder,
                                    downscale=self.downscale, test_every=self.hold_out,
                                    checkpoint=self.checkpoint, resume=self.resume,
                                    checkpoint_every=self.checkpoint_every,
                                    update_every=self.update_every, compact=self.compact)
        except (ValueError, OSError) as error:
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}

        if self.interactive and not bpy.app.background and context.window is not None:
            return self.start_background(context, background_training(request))

        wm = context.window_manager
        window = context.window is not None and not bpy.app.background
        printer = _printer("Training", self.update_every) if bpy.app.background else None

        def on_progress(p: Progress) -> None:
            if printer is not None:
                printer(p)
            if window and p.total:
                wm.progress_update(p.step)

        if window:
            wm.progress_begin(0, max(self.steps, 1))
        try:
            job = request.job(on_progress)
            job.run(raise_errors=False)  # errors are reported below, with the state reached
        finally:
            if window:
                wm.progress_end()
        level, message, obj = finish_training(request, job)
        if obj is not None:
            _make_active(context, obj)
        self.report({level}, message)
        if bpy.app.background:
            print(message, flush=True)
        return {"CANCELLED"} if level == "ERROR" else {"FINISHED"}


class SPLAT_OT_train_stop(bpy.types.Operator):
    """Stop background training after the current step, keeping the last state (a checkpoint
    is saved)"""

    bl_idname = "splat.train_stop"
    bl_label = "Stop Training"

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


def _menu(self, context):
    layout = self.layout
    layout.separator()
    layout.operator(SPLAT_OT_train.bl_idname, text="Train Gaussians", icon="SHADERFX")
    if RUNNING:
        layout.operator(SPLAT_OT_train_stop.bl_idname, text="Stop Training", icon="CANCEL")


def menu_parent():
    """The 3D View's Gaussian Splats submenu when the edit operators made one, else Object."""
    return getattr(bpy.types, "VIEW3D_MT_splat", None) or bpy.types.VIEW3D_MT_object


@bpy.app.handlers.persistent
def _on_load_pre(*_args) -> None:
    stop_all()
    RUNNING.clear()


CLASSES = (SPLAT_OT_train, SPLAT_OT_train_stop)
_MENU_PARENTS: list = []


def register() -> None:
    register_classes(CLASSES)
    parent = menu_parent()
    parent.remove(_menu)
    parent.append(_menu)
    _MENU_PARENTS.append(parent)
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
    for parent in _MENU_PARENTS:
        parent.remove(_menu)
    _MENU_PARENTS.clear()
    unregister_classes(CLASSES)
