"""Training Gaussians in Blender: `bpy.ops.splat.train` on an imported COLMAP scene, and
`train_colmap_collection()` for scripts.

    bpy.ops.splat.train(collection="garden")   # blocks; until done, as many Gaussians as needed
    bpy.ops.splat.train(collection="garden", steps=7000, max_gaussians=200_000)   # fixed count
    bpy.ops.splat.train("INVOKE_DEFAULT")      # the menu's way: a dialog, then in the background

The defaults are `TrainConfig`'s, shared with Bake to Splats (`TrainingSettings`): no step
count (train until the held-out PSNR gains less than 0.1 dB a minute), the "auto" strategy
(the count follows from the photos; Max Gaussians is a ceiling), compaction afterwards.

    from addon.blender.train.operator import train_colmap_collection
    obj = train_colmap_collection(bpy.data.collections["garden"], TrainConfig(steps=3000))

Which scene: the COLMAP collection made by `splat.import_colmap` (it carries
`colmap_transform`, the model folder and the image folder), found from the `collection`
property, else the active object's collection, else the active collection in the outliner,
else the only COLMAP collection in the scene.

The cameras are the collection's camera objects as they are in the scene (`source_of`; see
`addon/core/train/colmap_source.py` for the one path a camera takes): each renders at its recorded
COLMAP resolution and is matched to its photo by `colmap_image_name` (the first by object name
when a camera was duplicated). The photos are read from the model and image folder the
collection names (or `image_folder`, e.g. a downscaled `images_4`); training starts from the
collection's points object as it is in the world, else from the model's points where the import
put them. So the splats are trained in the Blender world: cameras moved together with the points
(a rig) train splats in the new place; a camera moved alone trains with the moved camera, which
no longer sees what its photo shows.

The splat object: `<collection> Splats` in the collection (the collection's `splat_object`
property points at it; identity transform), created on the first update and rewritten on every
later one and on every later training of the same collection. Its `splat_trained_steps` (and,
when the held-out views were evaluated, `splat_heldout_psnr` / `splat_heldout_ssim`) say what
it holds.

How it runs (blocking from scripts, in the background with a status bar and Esc from the menu):
`addon/blender/job_runner.py`. No redo panel (bl_options has no REGISTER): redoing would train
again.

Checkpoints hold the whole optimiser state (`Trainer.save_checkpoint`). Saved every
`checkpoint_every` steps and at the end (also when stopped), at `checkpoint` or by default in
`<blend name>_splats/<collection>.npz` beside the saved .blend, or, for an unsaved file, in the
user cache folder (`~/.cache/gaussian-splatting/checkpoints` on Linux). The path used is kept on
the collection (`splat_checkpoint`), so `resume` finds it even after the .blend is saved
elsewhere. `resume=True` continues from it up to `steps` total steps (the budget and threads
may change; the SH degree is the checkpoint's); the Gaussians are in the world the cameras had
when they were trained, so resume with the cameras where they were.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import bpy
import numpy as np
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, StringProperty

from ...core.train import colmap_source
from ...core.train.colmap_source import ColmapSource, TrainRequest
from ...core.train.dataset import MAX_WIDTH, NO_CAMERA, Points
from ...core.gaussians import Gaussians
from ...core.jobs import Progress, TrainingJob, compaction_note, how_far
from ...core.train.trainer import TrainConfig
from ...core.train.config import STRATEGY_NAMES
from .. import dependencies, job_runner, splat_object, viewport
from ..blender_splats import any_splats
from ..camera_adapter import camera_of
from ..sources import live
from ..job_runner import JobOperator, OperatorJob, draw_settings
from ..registration import module_registration

COLMAP_KEY = "colmap_transform"
OBJECT_KEY = "splat_object"
CHECKPOINT_KEY = "splat_checkpoint"
MODULES = ("splatcore", "OpenImageIO", "pycolmap")  # kernels, photos, the model
FEATURE = "Training Gaussians"


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


def _camera_objects(collection) -> dict:
    """Image name -> its camera object (the first by object name when duplicated)."""
    found = {}
    for obj in sorted(collection.all_objects, key=lambda o: o.name):
        name = obj.get("colmap_image_name") if obj.type == "CAMERA" else None
        if name is not None and name not in found:
            found[str(name)] = obj
    return found


def scene_points(collection) -> Points | None:
    """The collection's COLMAP points object (mesh or point cloud with `colmap_point_id`) in
    world space, with its colours; None when there is none."""
    for obj in collection.all_objects:
        data = getattr(obj, "data", None)
        attributes = getattr(data, "attributes", None)
        if attributes is None or not {"colmap_point_id", "position"} <= set(attributes.keys()):
            continue
        n = len(attributes["position"].data)
        xyz = np.empty(n * 3, np.float32)
        attributes["position"].data.foreach_get("vector", xyz)
        m = np.array(obj.matrix_world, np.float64)
        xyz = xyz.reshape(-1, 3).astype(np.float64) @ m[:3, :3].T + m[:3, 3]
        rgb = np.full((n, 3), 0.5)
        colour = attributes.get("color")
        if colour is not None and colour.data_type in ("BYTE_COLOR", "FLOAT_COLOR"):
            rgba = np.empty(n * 4, np.float32)
            colour.data.foreach_get("color_srgb", rgba)
            rgb = rgba.reshape(-1, 4)[:, :3].astype(np.float64)
        return Points(xyz, rgb)
    return None


def source_of(collection, scene=None) -> ColmapSource:
    """What training needs from a COLMAP collection, read on the main thread: the folders, the
    camera objects as `Camera`s (`camera_adapter.camera_of` at their recorded resolution) and
    the points object."""
    if not is_colmap_collection(collection):
        raise ValueError(f"collection {collection.name!r} is not an imported COLMAP scene")
    render = (scene or bpy.context.scene).render
    cameras = {name: camera_of(obj, render, use_recorded=True)
               for name, obj in _camera_objects(collection).items()}
    for name, camera in cameras.items():
        if not camera.is_pinhole:  # training renders through pinhole cameras only
            raise ValueError(f"camera {name!r} of {collection.name!r} is {camera.model.lower()}: "
                             "training needs its COLMAP cameras perspective")
    undistorted = _absolute(collection.get("colmap_undistorted_dir", ""))
    folder = _absolute(collection.get("colmap_image_dir", "")) or \
        str(collection.get("colmap_image_folder", "images"))
    transform = np.array(collection[COLMAP_KEY], np.float64).reshape(4, 4)
    return ColmapSource(collection.name, _absolute(collection["colmap_model_dir"]), folder,
                        str(Path(undistorted).parent) if undistorted else None, transform,
                        cameras, scene_points(collection))


def checkpoint_path(collection, explicit: str = "", *, resume: bool = False) -> Path:
    """`explicit`, else (resuming) the one stored on the collection, else the default."""
    if explicit:
        return Path(bpy.path.abspath(explicit))
    stored = str(collection.get(CHECKPOINT_KEY, "") or "")
    if resume and stored and Path(stored).is_file():
        return Path(stored)
    blend = bpy.path.abspath(bpy.data.filepath) if bpy.data.filepath else ""
    return colmap_source.default_checkpoint(
        collection.name, str(collection.get("colmap_model_dir", "")), blend)


def _alive(obj):
    try:
        return obj if obj is not None and obj.name is not None else None
    except ReferenceError:
        return None


def write_splats(collection_name: str, gaussians: Gaussians, *, antialiased: bool = False,
                 step: int | None = None):
    """Write `gaussians` (world space) into the collection's splat object, creating it when
    there is none. Returns the object. Main thread only."""
    collection = bpy.data.collections.get(collection_name)
    obj = _alive(collection.get(OBJECT_KEY)) if collection is not None else None
    if obj is not None and any_splats.is_splat_source(obj) and obj.users:
        any_splats.replace_gaussians(obj, gaussians)  # either kind: a Blender splat cloud stays one
    else:
        target = collection if collection is not None else bpy.context.scene.collection
        obj = splat_object.create_splat_object(
            gaussians, f"{collection_name} Splats", collection=target, antialiased=antialiased,
            sh_degree=gaussians.degree)
        if collection is not None:
            collection[OBJECT_KEY] = obj
    if step is not None:
        obj["splat_trained_steps"] = int(step)
    return obj


def train_request(collection, config: TrainConfig | None = None, *, image_folder: str = "",
                  downscale: float = 1.0, test_every: int = 8, checkpoint: str | Path = "",
                  resume: bool = False, checkpoint_every: int = 1000, update_every: int = 200,
                  compact: bool = True, max_width: int = MAX_WIDTH) -> TrainRequest:
    """Read the collection and check the inputs on the main thread; raises ValueError /
    FileNotFoundError, or MissingModule (an ImportError) for a module training needs."""
    for module in MODULES:
        dependencies.require(module, FEATURE)
    path = checkpoint_path(collection, str(checkpoint), resume=resume)
    return colmap_source.train_request(
        source_of(collection), path, config, resume=resume, image_folder=image_folder,
        downscale=downscale, test_every=test_every, checkpoint_every=checkpoint_every,
        update_every=update_every, compact=compact, max_width=max_width)


class SceneBefore:
    """The collection's splat object as it was before a run, so that a run that fails leaves
    the scene as it found it: no half-trained object (periodic updates included)."""

    def __init__(self, collection_name: str) -> None:
        self.name = collection_name
        collection = bpy.data.collections.get(collection_name)
        obj = _alive(collection.get(OBJECT_KEY)) if collection is not None else None
        self.obj = obj if obj is not None and any_splats.is_splat_source(obj) else None
        self.gaussians = (any_splats.object_gaussians(obj, drop_hidden=False)
                          if self.obj is not None else None)
        self.steps = self.obj.get("splat_trained_steps") if self.obj is not None else None

    def restore(self) -> None:
        collection = bpy.data.collections.get(self.name)
        obj = _alive(collection.get(OBJECT_KEY)) if collection is not None else None
        if obj is not None and obj != self.obj:  # made by the failed run
            mesh = obj.data
            bpy.data.objects.remove(obj)
            if mesh is not None and not mesh.users:
                bpy.data.meshes.remove(mesh)
            del collection[OBJECT_KEY]
        elif obj is not None and self.gaussians is not None:
            any_splats.replace_gaussians(obj, self.gaussians)
            if self.steps is None:
                obj.pop("splat_trained_steps", None)
            else:
                obj["splat_trained_steps"] = self.steps


def without_unseen(gaussians: Gaussians, trainer) -> Gaussians:
    """`gaussians` without those no photo's camera renders. A stopped training leaves a few
    pushed far out (km away: the object's Dimensions and View Selected go with them) that
    compaction would have removed; leaving them out changes no render from the photos' cameras
    (`renderer.seen_by_any`). The checkpoint keeps them all, for Resume."""
    from ...core.render.renderer import seen_by_any

    seen = seen_by_any(gaussians, trainer.dataset.cameras,
                       antialiased=trainer.config.antialiased)
    return gaussians if seen.all() else gaussians.subset(seen)


def finish_training(request: TrainRequest, job: TrainingJob, *, write: bool = True,
                    before: SceneBefore | None = None) -> tuple[str, str, object]:
    """Main thread, after the job: the object gets the final Gaussians (unless not `write`),
    the collection the checkpoint path; after a failure, the object goes back to `before`.
    Returns (level, message, object or None)."""
    snapshot = job.final
    collection = bpy.data.collections.get(request.source.name)
    if job.error is not None and before is not None:
        before.restore()
        obj = before.obj
    elif snapshot is not None and job.trainer is not None and write:
        gaussians = snapshot[1]
        if job.progress().phase == "cancelled":
            gaussians = without_unseen(gaussians, job.trainer)
        obj = write_splats(request.source.name, gaussians,
                           antialiased=job.trainer.config.antialiased, step=snapshot[0])
    else:
        obj = _alive(collection.get(OBJECT_KEY)) if collection is not None else None
    if collection is not None and job.checkpoint_saved:
        collection[CHECKPOINT_KEY] = str(request.checkpoint)
    p = job.progress()
    if job.error is None and job.trainer is None:
        return "INFO", "Training cancelled while loading the photos: nothing changed", obj
    if job.error is not None:
        first = str(job.error).splitlines()[0] if str(job.error) else type(job.error).__name__
        if job.trainer is None:
            return "ERROR", f"Training could not start: {first}", obj
        return "ERROR", (f"Training failed at step {p.step}: {first} (the splat object is as it "
                         f"was before this run)"), obj
    if obj is not None and p.evaluation is not None and p.evaluation.views:
        obj["splat_heldout_psnr"] = p.evaluation.psnr
        obj["splat_heldout_ssim"] = p.evaluation.ssim
    name = f"'{obj.name}'" if obj is not None else "the splat object"
    where = f"; checkpoint {request.checkpoint}" if job.checkpoint_saved else ""
    if p.phase == "cancelled":
        return "INFO", (f"Training stopped at {how_far(p)}: {name} has "
                        f"{p.gaussians:,} Gaussians{where} (train again with Resume to "
                        f"continue)"), obj
    quality = ""
    if p.evaluation is not None and p.evaluation.views:
        quality = (f", held-out PSNR {p.evaluation.psnr:.2f} dB / SSIM "
                   f"{p.evaluation.ssim:.3f} on {p.evaluation.views} views")
    steps = f"{p.step:,} steps" if not p.start_step else f"from step {p.start_step:,} to {p.step:,}"
    message = (f"Trained {steps} in {p.elapsed:.1f} s: {name} has {p.gaussians:,} "
               f"Gaussians{quality}{compaction_note(job)}{where}")
    missing = job.trainer.dataset.scene.missing
    left_out = sorted(name for name, why in missing.items() if why == NO_CAMERA)
    if left_out:
        listed = ", ".join(left_out[:3]) + (", ..." if len(left_out) > 3 else "")
        return "WARNING", (f"{message} (left out, no camera object: {len(left_out)} "
                           f"photo{'s' if len(left_out) > 1 else ''}, {listed})"), obj
    return "INFO", message, obj


def look_through_a_photo(scene, collection, views) -> object | None:
    """After training in the UI: each 3D view in `views` (SpaceView3D) not already looking
    through a camera looks through a photo's (the scene camera when it is one of the
    collection's, else the first photo's). Seen from outside, a trained capture is its large
    background splats, a milky haze with the scene small in its middle; through a photo's camera
    it is the picture the training fit. Returns the camera, or None when nothing changed."""
    cameras = list(_camera_objects(collection).values()) if collection is not None else []
    views = [v for v in views if v.region_3d is not None
             and v.region_3d.view_perspective != "CAMERA"]
    if not cameras or not views:
        return None
    camera = scene.camera if scene.camera in cameras else cameras[0]
    scene.camera = camera
    for view in views:
        view.region_3d.view_perspective = "CAMERA"
    return camera


def _scene_views(scene) -> list:
    return [area.spaces.active for window in bpy.context.window_manager.windows
            if window.scene == scene for area in window.screen.areas if area.type == "VIEW_3D"]


def request_job(request: TrainRequest,
                on_progress: Callable[[Progress], None] | None = None) -> TrainingJob:
    """The request as a training job (not started): the photos load on the job's thread."""
    return TrainingJob(lambda job: request.make_trainer(job.loading), steps=request.config.steps,
                       checkpoint=request.checkpoint, checkpoint_every=request.checkpoint_every,
                       snapshot_every=request.update_every, compact_after=request.compact,
                       on_progress=on_progress)


def training_job(request: TrainRequest) -> OperatorJob:
    """The request as the job runner runs it: the job (not started), and what the main thread
    does with its snapshots and its end."""
    name = request.source.name
    before = SceneBefore(name)

    def target():
        collection = bpy.data.collections.get(name)
        return _alive(collection.get(OBJECT_KEY)) if collection is not None else None

    def apply(step, gaussians):
        # The first snapshot of a new object is written (the object exists from then on), the
        # later ones shown in its place until the end (`sources.live`: one redraw of the view
        # when their image is ready, not a depsgraph update and its redraw per anti-aliasing
        # sample).
        obj = target()
        if obj is None:
            write_splats(name, gaussians, antialiased=request.config.antialiased, step=step)
        else:
            live.show(obj, gaussians, step)
            viewport.refresh()

    def finish(running, write):
        live.end(target())
        level, message, obj = finish_training(request, running.job, write=write, before=before)
        scene = bpy.context.scene
        if level != "ERROR" and running.job.progress().phase == "done" and scene is not None \
                and not bpy.app.background:
            camera = look_through_a_photo(scene, bpy.data.collections.get(name),
                                          _scene_views(scene))
            if camera is not None:
                message += f" (the view looks through '{camera.name}')"
        return level, message, obj

    return OperatorJob(f"train:{name}", "Training", request_job(request), finish, apply, target)


def train_colmap_collection(collection, config: TrainConfig | None = None,
                            progress: Callable[[Progress], None] | None = None, **options):
    """Train on an imported COLMAP collection on the calling thread; returns the splat object
    (created or updated). `progress(Progress)` is called after every step. `options`: those of
    `train_request` (image_folder, downscale, test_every, checkpoint, resume, checkpoint_every,
    update_every, compact). Raises on bad input or a failure."""
    request = train_request(collection, config, **options)
    before = SceneBefore(collection.name)
    job = request_job(request, progress)
    job.run()
    return finish_training(request, job, before=before)[2]


# -- operators ------------------------------------------------------------------------------------

COMPACT_DESCRIPTION = "After training, prune negligible Gaussians and unneeded SH bands"
STRATEGY_ITEMS = {
    "auto": ("Automatic", "As many Gaussians as the images need: 3DGS-MCMC that grows while "
                          "added Gaussians still lower the training error, then settles"),
    "mcmc": ("MCMC", "3DGS-MCMC: grows 5 % every 100 steps up to Max Gaussians"),
    "default": ("Reference", "The reference 3DGS densification (clone, split, prune) within "
                             "Max Gaussians"),
}
_STRATEGY_ENUM = [(name, *STRATEGY_ITEMS[name]) for name in STRATEGY_NAMES]
_DEFAULTS = TrainConfig()


class TrainingSettings:
    """Settings both training operators share (Train Gaussians, Bake to Splats), with one set
    of defaults: `TrainConfig`'s."""

    steps: IntProperty(name="Steps (0: until done)", default=_DEFAULTS.steps, min=0, soft_max=30000,
                       description=f"A fixed number of optimisation steps; 0: until done, when "
                                   f"the held-out PSNR (with no held-out views, the training "
                                   f"views') gains less than "
                                   f"{_DEFAULTS.stop_below_db_per_minute} dB a minute of work "
                                   f"(a model of each step's cost, not the clock: the same "
                                   f"step on a busy machine; at most {_DEFAULTS.max_steps:,} "
                                   f"steps); it keeps the best state checked")
    max_gaussians: IntProperty(name="Max Gaussians", default=_DEFAULTS.max_gaussians, min=1,
                               soft_max=3_000_000,
                               description="A ceiling on the Gaussian count (Automatic sizes "
                                           "the model itself below it)")
    strategy: EnumProperty(name="Densification", default=_DEFAULTS.strategy,
                           items=_STRATEGY_ENUM,
                           description="How the Gaussians grow and move while training")
    compact: BoolProperty(name="Compact", default=True, description=COMPACT_DESCRIPTION)
    sh_degree: IntProperty(name="SH Degree", default=_DEFAULTS.sh_degree, min=0, max=3,
                           description="Spherical-harmonics bands to train (view-dependent colour)")
    seed: IntProperty(name="Seed", default=0, min=0)
    threads: IntProperty(name="Threads", default=0, min=0, soft_max=64,
                         description="Worker threads for the kernels (0: the scene's Gaussian "
                                     "Splats Threads, which with 0 is as many as Blender renders "
                                     "with; in the background every core but one at most)")
    update_every: IntProperty(name="Update Every", default=200, min=0, soft_max=2000,
                              description="Steps between updates of the splat object while "
                                          "training in the background, at most one every 3 s "
                                          "(0: only at the end)")


class SPLAT_OT_train(TrainingSettings, JobOperator, bpy.types.Operator):
    """Train Gaussians on the CPU from the photos of an imported COLMAP scene. From the menu it
    runs in the background (Esc stops it, keeping the last state); from scripts it blocks"""

    bl_idname = "splat.train"
    bl_label = "Train Gaussians"
    bl_options = {"UNDO"}  # no redo panel: redoing would train again

    collection: StringProperty(name="COLMAP Scene", description=(
        "The imported COLMAP collection (empty: the active object's, the active collection, or "
        "the scene's only one)"))
    image_folder: StringProperty(name="Image Folder", description=(
        "Photos to train on: a folder beside the model (images_2, images_4, ...) or an absolute "
        "path (empty: the import's)"))
    downscale: FloatProperty(name="Downscale", default=1.0, min=1.0, soft_max=8.0,
                             description="Divide the photos' size by this (faster, coarser)")
    max_width: IntProperty(name="Max Width", default=MAX_WIDTH, min=0, soft_max=8000,
                           subtype="PIXEL",
                           description="Photos wider than this train at this width, as the "
                                       "reference 3DGS code does (0: at their full size)")
    hold_out: IntProperty(name="Hold Out Every", default=8, min=0, soft_max=32,
                          description="Every n-th photo (by name) is a held-out test view "
                                      "(0: train on all)")
    antialiased: BoolProperty(name="Antialiased", default=False,
                              description="Train for the Mip-Splatting antialiased render mode")
    checkpoint_every: IntProperty(name="Checkpoint Every", default=1000, min=0, soft_max=10000,
                                  description="Steps between checkpoints (0: only at the end)")
    resume: BoolProperty(name="Resume", default=False,
                         description="Continue from the checkpoint (up to Steps in total)")
    checkpoint: StringProperty(name="Checkpoint", subtype="FILE_PATH",
                               description="Checkpoint file (empty: beside the .blend, or the "
                                           "user cache folder for an unsaved file)")

    DIALOG = ("collection", ("steps", "max_gaussians", "strategy", "sh_degree"),
              ("image_folder", "downscale", "max_width", "hold_out"),
              ("update_every", "checkpoint_every", "threads", "seed"),
              "antialiased", "compact", "resume", "checkpoint")

    @classmethod
    def poll(cls, context):
        if not dependencies.poll_unavailable(cls, MODULES, FEATURE):
            return False
        if not any(is_colmap_collection(c) for c in bpy.data.collections):
            cls.poll_message_set("Import a COLMAP scene first (File > Import > COLMAP Scene)")
            return False
        return True

    def draw(self, context):
        draw_settings(self.layout, self, self.DIALOG)

    def invoke(self, context, event):
        collection = find_colmap_collection(context, self.collection)
        if collection is not None:
            self.collection = collection.name
        return self.invoke_settings(context, "Train Gaussians", "Train")

    def execute(self, context):
        collection = find_colmap_collection(context, self.collection)
        if collection is None:
            self.report({"ERROR"}, f"no COLMAP collection named {self.collection!r}" if
                        self.collection else "no COLMAP scene to train: import one (File > "
                        "Import > COLMAP Scene) and select one of its cameras")
            return {"CANCELLED"}
        self.collection = collection.name
        config = TrainConfig(steps=self.steps, max_gaussians=self.max_gaussians,
                             strategy=self.strategy, sh_degree=self.sh_degree, seed=self.seed,
                             threads=self.job_threads(context, self.threads),
                             antialiased=self.antialiased)
        try:
            request = train_request(collection, config, image_folder=self.image_folder,
                                    downscale=self.downscale, max_width=self.max_width,
                                    test_every=self.hold_out,
                                    checkpoint=self.checkpoint, resume=self.resume,
                                    checkpoint_every=self.checkpoint_every,
                                    update_every=self.update_every, compact=self.compact)
        except (ValueError, OSError, ImportError) as error:
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}
        return self.run_job(context, training_job(request))


def _menu(self, context):
    layout = self.layout
    layout.separator()
    layout.operator(SPLAT_OT_train.bl_idname, text="Train Gaussians", icon="SHADERFX")
    if job_runner.RUNNING:
        layout.operator(job_runner.SPLAT_OT_train_stop.bl_idname, text="Stop Training",
                        icon="CANCEL")


CLASSES = (SPLAT_OT_train,)
register, unregister = module_registration(CLASSES, menus=[(job_runner.menu_parent, _menu)])
