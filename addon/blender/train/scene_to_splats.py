"""A Blender scene to splats ("Bake to Splats" in the menu): `bpy.ops.splat.bake_to_splats`,
and `scene_to_splats()` for scripts. (Splats to a mesh's texture is `mesh_convert` and
`addon/core/mesh/texture.py`.)

    bpy.ops.splat.bake_to_splats(cameras=64, resolution=(256, 256), samples=32,
                                 filepath="//chair.ply")

What it does:
1. Targets: the selected objects with geometry (meshes, curves, text, metaballs, ...; splat
   objects never), or every visible one when nothing is selected. Their evaluated bounding boxes
   give a bounding sphere (centre, radius).
2. Cameras: `cameras` views on a sphere of `radius_factor` x radius around the centre (a
   Fibonacci lattice, `addon.core.train.scene_to_splats.orbit_cameras`; the upper half only with
   `upper_hemisphere`), each looking at the centre with a field of view that frames the bounding
   sphere. Known poses: no COLMAP.
3. Renders: Cycles on the CPU at `resolution` with `samples` samples, transparent film (the
   world lights the scene but is not baked in), no compositor, no sequencer, no motion blur, no
   border, and (with `only_selected`, the default) every other object with geometry hidden from
   the render, so only the selection is baked; lights stay. Every scene setting touched (engine,
   device, samples, denoising, film, resolution, percentage, pixel aspect, output path and
   format, the scene camera, objects' render visibility, the splat compositing switch) is put
   back afterwards, also after an error; the temporary camera is removed.
4. Colour: Cycles writes premultiplied scene-linear RGBA; the targets are display sRGB (docs/conventions.md,
   "Colour": splats hold display sRGB, like splats trained on photos), converted with
   `addon.core.colour.display_from_linear` (the sRGB transfer curve on the straight colour, the
   "Standard" view transform) and clipped to [0, 1] (straight colour; premultiplied: [0, alpha]).
   The scene's view transform and look are not baked in: in Blender the splats then look like
   the meshes did under the same view transform; a web viewer shows them as "Standard" would.
5. Training (alpha-aware): every step composites the target over a fresh random background
   colour and renders the splats over the same colour
   (`addon.core.train.scene_to_splats.RandomBackground`), so transparent parts of the renders must
   stay transparent: no background, no dark fringe. The Gaussians start from `initial_points`
   points spread over the targets' surfaces (area-weighted, the material's base colour, else
   grey). By default every view trains (`hold_out` 0). The training settings and their defaults
   are Train Gaussians' (`train.operator.TrainingSettings`): until done (with no held-out
   views the stop test measures up to 8 training views), the "auto" strategy, compaction.
6. Output: a splat object `<object> Splats` (world space, identity transform) in the active
   collection, and the .ply at `filepath` (`addon.core.splat_io.save`, the standard 3DGS layout
   web viewers read). Empty `filepath`: `<blend>_<object>_splats.ply` beside the saved .blend,
   else the temporary folder; the report names it.

From the menu (`invoke`: a settings dialog) the renders block (Cycles, with the cursor showing
progress), then training runs in the background through `job_runner` like `splat.train` (status
bar, the object updating every `update_every` steps, Esc stops it keeping the last state, the
.ply is written either way). Scripts (`execute`) block until the .ply is written; headless, a
line is printed per stage and every few seconds.
"""

from __future__ import annotations

import math
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import bpy
import numpy as np
from bpy.props import BoolProperty, FloatProperty, IntProperty, IntVectorProperty, StringProperty

from ...core.images import files
from ...core import splat_io
from ...core.cameras import Camera, camera_to_blender
from ...core.colour import display_from_linear, srgb_encode
from ...core.train.dataset import Points
from ...core.jobs import TrainingJob, compaction_note
from ...core.train.scene_to_splats import (
    ImageDataset,
    RandomBackground,
    orbit_cameras,
    sample_surface,
)
from ...core.train.trainer import Trainer, TrainConfig
from .. import dependencies, splat_object
from ..blender_splats import any_splats
from ..camera_adapter import set_camera
from ..job_runner import JobOperator, OperatorJob, draw_settings, is_running, menu_parent, preparing
from ..registration import module_registration
from .operator import TrainingSettings

GEOMETRY_TYPES = {"MESH", "CURVE", "SURFACE", "META", "FONT", "CURVES", "POINTCLOUD", "VOLUME",
                  "GREASEPENCIL"}
SURFACE_TYPES = {"MESH", "CURVE", "SURFACE", "META", "FONT"}
GREY = 0.8  # linear grey for surfaces without a material
MODULES = ("splatcore", "OpenImageIO")  # kernels, the rendered views
FEATURE = "Baking a scene to splats"


class SceneToSplatsError(ValueError):
    """Nothing to bake, or a scene that cannot be rendered."""


# -- what to bake ---------------------------------------------------------------------------------

def _has_geometry(obj) -> bool:
    return obj.type in GEOMETRY_TYPES and not any_splats.is_splat_source(obj)


def targets_of(context) -> list:
    """The selected objects with geometry, else every visible one (never splat objects)."""
    selected = [o for o in context.selected_objects if _has_geometry(o)]
    if selected:
        return selected
    return [o for o in context.view_layer.objects if _has_geometry(o) and o.visible_get()]


def bounding_sphere(objects, depsgraph) -> tuple[np.ndarray, float]:
    """Centre and radius of the sphere around the objects' evaluated world bounding boxes."""
    corners = []
    for obj in objects:
        evaluated = obj.evaluated_get(depsgraph)
        m = np.array(evaluated.matrix_world, np.float64)
        box = np.array([tuple(c) for c in evaluated.bound_box], np.float64).reshape(-1, 3)
        corners.append(box @ m[:3, :3].T + m[:3, 3])
    if not corners:
        raise SceneToSplatsError("nothing to bake: select objects with geometry")
    points = np.concatenate(corners)
    low, high = points.min(0), points.max(0)
    radius = 0.5 * float(np.linalg.norm(high - low))
    if not radius > 0 or not math.isfinite(radius):
        raise SceneToSplatsError("the objects to bake have no extent")
    return 0.5 * (low + high), radius


def material_colour(material) -> np.ndarray:
    """Display-sRGB base colour of a material: the Principled BSDF's unlinked Base Color, else
    the viewport colour; grey without a material."""
    linear = np.full(3, GREY)
    if material is not None:
        linear = np.array(material.diffuse_color[:3], np.float64)
        tree = material.node_tree
        if tree is not None:
            for node in tree.nodes:
                if node.type == "BSDF_PRINCIPLED":
                    socket = node.inputs.get("Base Color")
                    if socket is not None and not socket.is_linked:
                        linear = np.array(socket.default_value[:3], np.float64)
                    break
    return np.clip(srgb_encode(np.clip(linear, 0.0, None)), 0.0, 1.0)


def surface_points(objects, depsgraph, count: int, rng: np.random.Generator,
                   centre: np.ndarray, radius: float) -> Points:
    """`count` points on the objects' evaluated surfaces (area-weighted) with their materials'
    colours; inside the bounding sphere, grey, when there are no surfaces (volumes, points)."""
    vertices, triangles, colours, offset = [], [], [], 0
    for obj in objects:
        if obj.type not in SURFACE_TYPES:
            continue
        evaluated = obj.evaluated_get(depsgraph)
        try:
            mesh = evaluated.to_mesh()
        except RuntimeError:
            continue
        try:
            if mesh is None or not len(mesh.polygons):
                continue
            mesh.calc_loop_triangles()
            n, t = len(mesh.vertices), len(mesh.loop_triangles)
            co = np.empty(n * 3, np.float32)
            mesh.vertices.foreach_get("co", co)
            tris = np.empty(t * 3, np.int32)
            mesh.loop_triangles.foreach_get("vertices", tris)
            slots = np.empty(t, np.int32)
            mesh.loop_triangles.foreach_get("material_index", slots)
            m = np.array(evaluated.matrix_world, np.float64)
            vertices.append(co.reshape(-1, 3).astype(np.float64) @ m[:3, :3].T + m[:3, 3])
            triangles.append(tris.reshape(-1, 3).astype(np.int64) + offset)
            palette = [material_colour(s.material) for s in evaluated.material_slots] or \
                [material_colour(None)]
            palette = np.array(palette)
            colours.append(palette[np.clip(slots, 0, len(palette) - 1)])
            offset += n
        finally:
            evaluated.to_mesh_clear()
    if triangles:
        xyz, rgb = sample_surface(np.concatenate(vertices), np.concatenate(triangles),
                                  np.concatenate(colours), count, rng)
        return Points(xyz, rgb)
    direction = rng.normal(size=(count, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    xyz = centre + direction * radius * np.cbrt(rng.random((count, 1)))
    return Points(xyz, np.full((count, 3), 0.5))


# -- rendering the views --------------------------------------------------------------------------

@dataclass
class SavedSettings:
    """Attribute values to put back, in reverse order of setting."""

    items: list = field(default_factory=list)

    @staticmethod
    def _value(value):
        if isinstance(value, (str, bytes, bpy.types.ID)) or not hasattr(value, "__len__"):
            return value
        return tuple(value)  # arrays: a copy, not a view of the property

    def remember(self, owner, *names: str) -> None:
        """Record values before anything changes them (setting one may change another: the
        file format changes the colour depth)."""
        for name in names:
            key = (owner.as_pointer(), name)
            if hasattr(owner, name) and all((o.as_pointer(), n) != key for o, n, _ in self.items):
                self.items.append((owner, name, self._value(getattr(owner, name))))

    def set(self, owner, name: str, value) -> None:
        if not hasattr(owner, name):
            return
        self.remember(owner, name)
        if self._value(getattr(owner, name)) != self._value(value):
            setattr(owner, name, value)

    def restore(self) -> None:
        # Twice: a value may be invalid until a later-restored one is back (an EXR-only colour
        # depth before the file format), the second pass sets it.
        for _ in range(2):
            for owner, name, value in reversed(self.items):
                try:
                    if self._value(getattr(owner, name)) != value:
                        setattr(owner, name, value)
                except (ReferenceError, AttributeError, TypeError, ValueError):
                    pass
        self.items.clear()


def rgba_to_target(rgba: np.ndarray) -> np.ndarray:
    """Cycles' premultiplied scene-linear RGBA -> the premultiplied display-sRGB training target
    (see the module docstring: `display_from_linear`, straight colour clipped to [0, 1])."""
    out = display_from_linear(np.asarray(rgba, np.float32))
    alpha = np.clip(out[..., 3:4], 0.0, 1.0)
    out[..., :3] = np.clip(out[..., :3], 0.0, np.where(alpha > 0, alpha, 1.0))
    out[..., 3:4] = alpha
    return np.ascontiguousarray(out, np.float32)


def render_views(scene, cameras: list[Camera], *, samples: int = 32, denoise: bool = False,
                 hide: list = (), progress=None) -> list[np.ndarray]:
    """Render `scene` with Cycles (CPU) from each camera; premultiplied display-sRGB RGBA
    targets. Every setting touched is restored, the temporary camera removed, also on error."""

    if not hasattr(scene, "cycles"):
        raise SceneToSplatsError("Cycles is not available in this Blender (enable the Cycles "
                                 "add-on)")
    folder = Path(tempfile.mkdtemp(prefix="splat-views-"))
    data = bpy.data.cameras.new("Splat View Camera")
    cam_obj = bpy.data.objects.new("Splat View Camera", data)
    saved = SavedSettings()
    images = []
    try:
        scene.collection.objects.link(cam_obj)
        render = scene.render
        first = camera_to_blender(cameras[0])
        saved.set(scene, "camera", cam_obj)
        saved.set(render, "engine", "CYCLES")
        saved.set(scene.cycles, "device", "CPU")
        saved.set(scene.cycles, "samples", int(samples))
        saved.set(scene.cycles, "use_denoising", bool(denoise))
        saved.set(scene.cycles, "use_animated_seed", False)
        saved.set(render, "film_transparent", True)
        saved.set(render, "resolution_x", first.resolution_x)
        saved.set(render, "resolution_y", first.resolution_y)
        saved.set(render, "resolution_percentage", first.resolution_percentage)
        saved.set(render, "pixel_aspect_x", 1.0)
        saved.set(render, "pixel_aspect_y", 1.0)
        saved.set(render, "use_border", False)
        saved.set(render, "use_single_layer", True)
        saved.set(render, "use_multiview", False)
        saved.set(render, "use_motion_blur", False)
        saved.set(render, "use_compositing", False)
        saved.set(render, "use_sequencer", False)
        saved.set(render, "use_file_extension", True)
        saved.set(render, "filepath", str(folder / "view.exr"))
        settings = render.image_settings
        saved.remember(settings, "media_type", "file_format", "color_mode", "color_depth",
                       "exr_codec")
        saved.set(settings, "media_type", "IMAGE")
        saved.set(settings, "file_format", "OPEN_EXR")
        saved.set(settings, "color_mode", "RGBA")
        saved.set(settings, "color_depth", "32")
        saved.set(settings, "exr_codec", "NONE")
        splat_render = getattr(scene, "splat_render", None)
        if splat_render is not None:  # no splats composited into the bake's own renders
            saved.set(splat_render, "enabled", False)
        for obj in hide:
            saved.set(obj, "hide_render", True)
        for i, camera in enumerate(cameras):
            params = camera_to_blender(camera)
            set_camera(cam_obj, params)
            data.clip_start, data.clip_end = _clip_range(camera, scene)
            path = folder / f"view_{i:03d}.exr"
            render.filepath = str(path)
            bpy.ops.render.render(write_still=True, scene=scene.name)
            if not path.is_file():
                raise SceneToSplatsError(f"Cycles wrote no image for view {i} (expected {path})")
            rgba = files.to_float(files.read_pixels(path))
            if rgba.shape[2] < 4:
                opaque = np.ones(rgba.shape[:2] + (1,), np.float32)
                rgba = np.concatenate([rgba[..., :3], opaque], axis=2)
            images.append(rgba_to_target(rgba[..., :4]))
            if progress is not None:
                progress((i + 1) / len(cameras), f"rendered view {i + 1} of {len(cameras)}")
    finally:
        saved.restore()
        bpy.data.objects.remove(cam_obj)
        bpy.data.cameras.remove(data)
        shutil.rmtree(folder, ignore_errors=True)
    return images


def _clip_range(camera: Camera, scene) -> tuple[float, float]:
    distance = float(np.linalg.norm(camera.centre))
    return 1e-3 * max(distance, 1e-3), 1e3 * max(distance, 1.0) + 1e4


# -- training on the views -----------------------------------------------------------------------

@dataclass
class SceneToSplatsRequest:
    """Everything a bake needs, gathered on the main thread."""

    scene_name: str
    dataset: ImageDataset
    config: TrainConfig
    filepath: Path
    name: str
    collection_name: str
    compact: bool = True
    update_every: int = 200
    background_seed: int = 0

    def job(self, on_progress=None) -> TrainingJob:
        backgrounds = RandomBackground(self.dataset, seed=self.background_seed)
        return TrainingJob(lambda job: Trainer(self.dataset, self.config), steps=self.config.steps,
                           snapshot_every=self.update_every, before_step=backgrounds,
                           after_training=backgrounds.finish, compact_after=self.compact,
                           evaluate=True, on_progress=on_progress,
                           loading_message="starting from the surface points")


def default_ply_path(name: str) -> Path:
    safe = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name) or "splats"
    if bpy.data.filepath:
        blend = Path(bpy.path.abspath(bpy.data.filepath))
        return blend.parent / f"{blend.stem}_{safe}.ply"
    return Path(tempfile.gettempdir()) / f"{safe}.ply"


def prepare_scene_to_splats(context, *, cameras: int = 64, resolution=(256, 256), samples: int = 32,
                 denoise: bool = False, steps: int = TrainConfig.steps,
                 max_gaussians: int = TrainConfig.max_gaussians,
                 strategy: str = TrainConfig.strategy,
                 sh_degree: int = 3, radius_factor: float = 2.5, upper_hemisphere: bool = False,
                 only_selected: bool = True, initial_points: int = 10_000, hold_out: int = 0,
                 seed: int = 0, threads: int = 0, compact: bool = True, update_every: int = 200,
                 filepath: str = "", progress=None) -> SceneToSplatsRequest:
    """Pick the targets, place the cameras, render the views and build the dataset (main
    thread: this is where Cycles runs). Raises SceneToSplatsError, or MissingModule (an
    ImportError) for a module it needs."""
    for module in MODULES:
        dependencies.require(module, FEATURE)
    scene = context.scene
    targets = targets_of(context)
    if not targets:
        raise SceneToSplatsError("nothing to bake: the scene has no visible objects with "
                                 "geometry")
    depsgraph = context.evaluated_depsgraph_get()
    centre, radius = bounding_sphere(targets, depsgraph)
    width, height = (int(v) for v in resolution)
    views = orbit_cameras(centre, radius, int(cameras), width, height,
                          distance_factor=float(radius_factor), upper_only=upper_hemisphere)
    rng = np.random.default_rng(seed)
    points = surface_points(targets, depsgraph, max(1, min(initial_points, max_gaussians)), rng,
                            centre, radius)
    hide = []
    if only_selected:
        chosen = set(targets)
        hide = [o for o in scene.objects if o.type in GEOMETRY_TYPES and o not in chosen]
    hide += [o for o in scene.objects if any_splats.is_splat_source(o) and o not in hide]
    images = render_views(scene, views, samples=samples, denoise=denoise, hide=hide,
                          progress=progress)
    dataset = ImageDataset(views, images, points, test_every=hold_out)
    name = f"{targets[0].name} Splats" if len(targets) == 1 else "Baked Splats"
    config = TrainConfig(steps=int(steps), max_gaussians=int(max_gaussians), strategy=strategy,
                         sh_degree=int(sh_degree), seed=int(seed), threads=int(threads),
                         max_initial_points=max(1, int(initial_points)))
    path = Path(bpy.path.abspath(filepath)) if filepath else default_ply_path(name)
    collection = getattr(context, "collection", None) or scene.collection
    return SceneToSplatsRequest(scene.name, dataset, config, path, name, collection.name, compact,
                       update_every, background_seed=seed)


def _collection(name: str):
    collection = bpy.data.collections.get(name)
    if collection is not None:
        return collection
    return bpy.context.scene.collection


def write_splats(request: SceneToSplatsRequest, gaussians, obj=None, *, final: bool = False):
    """Create or rewrite the bake's splat object (identity transform: world space)."""
    try:
        alive = obj is not None and obj.name is not None and obj.users > 0
    except ReferenceError:
        alive = False
    if alive:
        any_splats.replace_gaussians(obj, gaussians)  # an object converted to Blender's splats stays one
    else:
        obj = splat_object.create_splat_object(
            gaussians, request.name, collection=_collection(request.collection_name),
            sh_degree=gaussians.degree, source_path=str(request.filepath) if final else "")
    if final:
        obj.splat.source_path = str(request.filepath)
        obj.splat.sh_degree = gaussians.degree
    return obj


def finish_scene_to_splats(request: SceneToSplatsRequest, job: TrainingJob, obj=None, *,
                write: bool = True) -> tuple[str, str, object]:
    """Main thread, after training: the .ply and (when `write`) the object get the final
    Gaussians."""
    snapshot = job.final
    p = job.progress()
    if snapshot is None:
        if job.error is None:
            return "INFO", "Baking cancelled before training started: nothing changed", obj
        first = str(job.error).splitlines()[0] or type(job.error).__name__
        return "ERROR", f"Baking failed: {first}", obj
    gaussians = snapshot[1]
    request.filepath.parent.mkdir(parents=True, exist_ok=True)
    splat_io.save(gaussians, request.filepath)
    if not write:
        return "WARNING", f"Baked {request.filepath}; the splat object was not updated", obj
    obj = write_splats(request, gaussians, obj, final=True)
    obj["splat_trained_steps"] = int(snapshot[0])
    trainer = job.trainer
    quality = ""
    if trainer is not None and job.error is None:
        evaluation = p.evaluation  # held-out views, evaluated by the job
        if evaluation is None or not evaluation.views:
            evaluation = trainer.evaluate(trainer.dataset.train_indices[:8])
        obj["splat_bake_psnr"] = evaluation.psnr
        which = "held-out" if trainer.dataset.test_indices else "training"
        quality = f", {which} PSNR {evaluation.psnr:.2f} dB over {evaluation.views} views"
    if job.error is not None:
        return "ERROR", (f"Baking failed at step {p.step}: {job.error}; the last state is in "
                         f"'{obj.name}' and {request.filepath}"), obj
    state = (f"stopped at step {snapshot[0]:,}" if p.phase == "cancelled" else
             f"trained {snapshot[0]:,} steps")
    return "INFO", (f"Baked {len(request.dataset)} views, {state}: "
                    f"'{obj.name}' has {len(gaussians):,} Gaussians{quality}"
                    f"{compaction_note(job)}; wrote "
                    f"{request.filepath}"), obj


def scene_to_splats_job(request: SceneToSplatsRequest) -> OperatorJob:
    """The request as the job runner runs it (see `operator.training_job`)."""
    state = {"object": None}

    def apply(step, gaussians):
        state["object"] = write_splats(request, gaussians, state["object"])

    def finish(running, write):
        return finish_scene_to_splats(request, running.job, state["object"], write=write)

    return OperatorJob(f"bake:{request.name}", "Baking", request.job(), finish, apply,
                       lambda: state["object"])


def scene_to_splats(context=None, progress=None, **options):
    """Render, train and write on the calling thread; returns the splat object. `options`: those
    of `prepare_scene_to_splats`. `progress(Progress)` is called after every training step."""
    context = context or bpy.context
    request = prepare_scene_to_splats(context, **options)
    job = request.job(progress)
    job.run()
    level, message, obj = finish_scene_to_splats(request, job)
    if level == "ERROR":
        raise SceneToSplatsError(message)
    return obj


class SPLAT_OT_bake_to_splats(TrainingSettings, JobOperator, bpy.types.Operator):
    """Render the selected objects with Cycles from cameras all around them and train Gaussian
    splats on the renders: a splat object and a .ply that web viewers open"""

    bl_idname = "splat.bake_to_splats"
    bl_label = "Bake to Splats"
    bl_options = {"UNDO"}  # no redo panel: redoing would train again

    cameras: IntProperty(name="Cameras", default=64, min=1, soft_max=512,
                         description="Views rendered around the selection")
    resolution: IntVectorProperty(name="Resolution", size=2, default=(256, 256), min=8,
                                  soft_max=2048, description="Width and height of each view")
    samples: IntProperty(name="Samples", default=32, min=1, soft_max=1024,
                         description="Cycles samples per view")
    denoise: BoolProperty(name="Denoise", default=False,
                          description="Denoise the renders (cleaner targets at few samples)")
    radius_factor: FloatProperty(
        name="Distance", default=2.5, min=1.05, soft_max=10.0,
        description="Camera distance from the centre, in bounding-sphere radii")
    upper_hemisphere: BoolProperty(name="Upper Hemisphere Only", default=False,
                                   description="Cameras only above the centre (things standing "
                                               "on the ground)")
    only_selected: BoolProperty(name="Only Selected", default=True,
                                description="Hide every other object with geometry from the "
                                            "renders (lights stay)")
    initial_points: IntProperty(name="Initial Points", default=10_000, min=1, soft_max=200_000,
                                description="Gaussians to start from, spread over the surfaces")
    hold_out: IntProperty(name="Hold Out Every", default=0, min=0, soft_max=32,
                          description="Every n-th view is held out to measure quality (0: all "
                                      "views train)")
    filepath: StringProperty(name="Output", subtype="FILE_PATH",
                             description="The .ply to write (empty: beside the .blend, or the "
                                         "temporary folder)")

    DIALOG = (("cameras", "resolution", "samples", "denoise", "radius_factor",
               "upper_hemisphere", "only_selected"),
              ("steps", "max_gaussians", "strategy", "sh_degree", "initial_points", "compact"),
              ("hold_out", "update_every", "threads", "seed"), "filepath")

    @classmethod
    def poll(cls, context):
        return (dependencies.poll_unavailable(cls, MODULES, FEATURE) and context.scene is not None
                and getattr(context, "view_layer", None) is not None)

    def draw(self, context):
        draw_settings(self.layout, self, self.DIALOG)

    def invoke(self, context, event):
        return self.invoke_settings(context, "Bake to Splats", "Bake")

    def _options(self) -> dict:
        return dict(cameras=self.cameras, resolution=tuple(self.resolution), samples=self.samples,
                    denoise=self.denoise, steps=self.steps, max_gaussians=self.max_gaussians,
                    strategy=self.strategy, sh_degree=self.sh_degree, radius_factor=self.radius_factor,
                    upper_hemisphere=self.upper_hemisphere, only_selected=self.only_selected,
                    initial_points=self.initial_points, hold_out=self.hold_out, seed=self.seed,
                    threads=self.threads, compact=self.compact, update_every=self.update_every,
                    filepath=self.filepath)

    def execute(self, context):
        if is_running("bake:"):
            self.report({"ERROR"}, "a bake is already training")
            return {"CANCELLED"}
        try:
            options = self._options() | {"threads": self.job_threads(context, self.threads)}
            with preparing(context, "Baking", "rendering views") as progress:
                request = prepare_scene_to_splats(context, progress=progress, **options)
        except (SceneToSplatsError, ValueError, RuntimeError, OSError, ImportError) as error:
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}
        return self.run_job(context, scene_to_splats_job(request))


def _menu(self, context):
    self.layout.operator(SPLAT_OT_bake_to_splats.bl_idname, text="Bake to Splats",
                         icon="RENDER_STILL")


CLASSES = (SPLAT_OT_bake_to_splats,)
register, unregister = module_registration(CLASSES, menus=[(menu_parent, _menu)])
