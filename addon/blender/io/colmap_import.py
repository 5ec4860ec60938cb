"""COLMAP scenes into Blender: File > Import > COLMAP scene, and `import_colmap()` for scripts.

    bpy.ops.splat.import_colmap(directory="/path/to/workspace", image_folder="images", align=True)

    from addon.blender.io.colmap_import import import_colmap
    collection = import_colmap("/path/to/workspace", image_folder="images_4", align=True)

What it builds, in one new collection (named after the workspace) linked to the scene:

- one camera object per registered image, named after the image, with exact intrinsics
  (`cameras.camera_to_blender`: lens and a 36 mm sensor fitted horizontally, shifts for the
  principal point, pixel aspect for fx != fy) and custom properties:
  `colmap_image_name` (with subfolders), `colmap_image_id`, `colmap_camera_id`,
  `colmap_resolution` (width, height), `colmap_resolution_percentage`,
  `colmap_pixel_aspect` (x, y) and `colmap_photo` (the photo matching the camera; "" if
  missing). Blender's render size is per scene, not per camera: making a camera the scene
  camera, a render's start and a frame change (marker cameras) set the scene's resolution and
  pixel aspect from them while the scene's `colmap_camera_output` switch is on (Output
  Properties > Format; see "per-camera render settings" below); so do
  `apply_camera_resolution()` and the "Set COLMAP camera" operator;
- optionally the photos as camera background images (stretched over the camera frame, which
  they fit exactly);
- the sparse points as a point cloud object with attributes `color` (sRGB bytes), `error`,
  `track_length` and `colmap_point_id`, and a material that shows the colour; shown in the
  viewport but left out of final renders (`render_points=True` keeps them in);
- optionally a camera that follows the images in name order, one frame each (exact on every
  frame when all images share one size; the scene takes the first image's resolution).

The collection carries `colmap_transform` (16 floats, row-major 4x4 similarity from COLMAP's
frame to Blender's world: identity unless aligned), `colmap_model_dir`, `colmap_image_dir`,
`colmap_image_folder`, `colmap_undistorted_dir`, `colmap_alignment`, `colmap_missing`,
`colmap_dropped` (what the reader left out as non-finite, with counts) and
`colmap_warnings` (one a line, e.g. photos of an LLFF-style folder matched by sorted order).

Bad input (see `addon.core.colmap`) raises `ColmapError` before anything is created; a failure
while building removes everything built so far. The operator reports either as an error.
"""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

import bpy
import numpy as np
from bpy.props import BoolProperty, EnumProperty, FloatProperty, StringProperty

from ...core import colmap
from ...core.cameras import camera_to_blender
from .. import dependencies
from ...core.jobs import WAIT_STEP, StagedJob
from ..camera_adapter import (
    apply_recorded_output,
    marker_camera,
    record_output_settings,
    recorded_output,
    set_camera,
    set_lens,
    to_matrix,
)
from ..job_runner import JobOperator, OperatorJob
from . import photo_scene
from ..registration import module_registration
from ..render import hooks

SENSOR_WIDTH = 36.0


# -- per-camera render settings ----------------------------------------------------------------
#
# Blender keeps one output size and pixel aspect per scene; each COLMAP camera records its
# photo's. They are applied, while the scene's `colmap_camera_output` switch is on, when:
#   - a camera becomes the scene camera in the UI (message bus on Scene.camera);
#   - a render starts (render_init: F12, `blender -b -f N`, scripts), for the camera the
#     current frame's markers bind (Blender switches marker cameras after that handler);
#   - the frame changes (frame_change_post: scrubbing past a marker that binds a camera).
# An animation render keeps the size it started with for every frame (Blender's pipeline reads
# it once), so during one nothing is changed; a frame whose camera recorded another size is
# reported on the terminal instead (render such frames one by one: F12, `-f N`, or the
# `render` command-line verb, which does).

SWITCH = "colmap_camera_output"  # Scene property: the switch above
_rendering = {"active": False, "warned": set(), "frame": None, "output": None}


def apply_camera_resolution(scene: bpy.types.Scene, camera_obj: bpy.types.Object | None = None) -> bool:
    """Set the scene's resolution, percentage and pixel aspect from an imported camera
    (`camera_obj`, default the scene camera). False (nothing changed) for other cameras.
    Applies whatever the scene's switch says (the handlers check it)."""
    return apply_recorded_output(scene.render, camera_obj if camera_obj is not None else scene.camera)


def _switch_on(scene) -> bool:
    return scene is not None and bool(getattr(scene, SWITCH, True))


_MSGBUS_OWNER = object()


def _on_scene_camera_changed() -> None:
    scene = getattr(bpy.context, "scene", None)
    if _switch_on(scene) and not _rendering["active"]:
        apply_camera_resolution(scene)


def _subscribe() -> None:
    bpy.msgbus.clear_by_owner(_MSGBUS_OWNER)
    bpy.msgbus.subscribe_rna(key=(bpy.types.Scene, "camera"), owner=_MSGBUS_OWNER, args=(),
                             notify=_on_scene_camera_changed)


@bpy.app.handlers.persistent
def _on_load_post(*_args) -> None:
    _subscribe()


def _output(render) -> tuple:
    return (render.resolution_x, render.resolution_y, render.resolution_percentage,
            render.pixel_aspect_x, render.pixel_aspect_y)


@bpy.app.handlers.persistent
def _on_render_init(scene, *_args) -> None:
    if _switch_on(scene):
        camera = marker_camera(scene, scene.frame_current) or scene.camera
        apply_camera_resolution(scene, camera)
    # What this render started with: a still render renders only this frame at this size
    _rendering.update(active=True, warned=set(), frame=scene.frame_current,
                      output=_output(scene.render))


@bpy.app.handlers.persistent
def _on_render_end(*_args) -> None:
    _rendering["active"] = False


@bpy.app.handlers.persistent
def _on_frame_change(scene, *_args) -> None:
    # Markers first: `Scene.frame_set` runs this handler before it switches the camera.
    camera = marker_camera(scene, scene.frame_current) or scene.camera
    if not _switch_on(scene) or camera is None:
        return
    if not _rendering["active"]:
        apply_camera_resolution(scene, camera)
        return
    # Only an animation's later frames: F12 (one frame, the one the render started on) never
    # gets the message (it did, in 4.3 and 5.2's UI, naming a camera that was not rendering)
    wanted = recorded_output(camera)
    if wanted is None or camera.name in _rendering["warned"] or \
            scene.frame_current == _rendering.get("frame"):
        return
    started = _rendering["output"]  # aspects are stored float32
    if not np.allclose(wanted, started, rtol=1e-6, atol=0.0):
        _rendering["warned"].add(camera.name)
        print(f"Gaussian Splatting: frame {scene.frame_current}: camera {camera.name!r} "
              f"recorded {wanted[0]}x{wanted[1]} at {wanted[2]} % (pixel aspect {wanted[3]:g}:"
              f"{wanted[4]:g}), but an animation renders every frame at the size it started "
              f"with; render its frames one by one (F12, blender -b file.blend -f N, or "
              f"blender -c gaussian_splatting render) to match its photo")


_HANDLERS = (("load_post", _on_load_post), ("render_init", _on_render_init),
             ("render_complete", _on_render_end), ("render_cancel", _on_render_end),
             ("frame_change_post", _on_frame_change))


def _draw_switch(self, context) -> None:
    if context.scene is not None:
        self.layout.prop(context.scene, SWITCH)


# -- building ----------------------------------------------------------------------------------

class _Built:
    """Every datablock made so far, to remove them all if building fails."""

    def __init__(self) -> None:
        self.ids: list = []

    def add(self, block):
        self.ids.append(block)
        return block

    def remove_all(self) -> None:
        collections = {
            bpy.types.Object: bpy.data.objects, bpy.types.Camera: bpy.data.cameras,
            bpy.types.Image: bpy.data.images, bpy.types.Mesh: bpy.data.meshes,
            bpy.types.PointCloud: bpy.data.pointclouds, bpy.types.Material: bpy.data.materials,
            bpy.types.Action: bpy.data.actions, bpy.types.Collection: bpy.data.collections,
        }
        for block in reversed(self.ids):
            try:
                name = block.name  # raises ReferenceError once removed
            except ReferenceError:
                continue
            for kind, data in collections.items():
                if isinstance(block, kind) and data.get(name) == block:
                    data.remove(block)
                    break


def _clip_range(scene_data: colmap.ColmapScene) -> tuple[float, float]:
    """Clip distances that hold the scene: from the points' depths in the cameras."""
    depths = []
    for im in scene_data.images[:: max(1, len(scene_data.images) // 50)]:
        rows = scene_data.points.positions_of(im.point3D_ids)
        xyz = scene_data.points.xyz[rows[rows >= 0]]
        if len(xyz):
            w2c = im.camera.world_to_camera
            depths.append(xyz @ w2c[2, :3] + w2c[2, 3])
    if not depths:
        return 0.1, 1000.0
    z = np.concatenate(depths)
    z = z[z > 0]
    if not len(z):
        return 0.1, 1000.0
    return float(max(np.percentile(z, 1) * 0.02, 1e-6)), float(np.percentile(z, 99) * 50.0)


def _points_object(name: str, points: colmap.ColmapPoints, radius: float, collection, scene,
                   built: _Built) -> bpy.types.Object:
    """A point cloud object (a vertex-only mesh converted by Blender; it stays a mesh where
    the conversion is not available)."""
    mesh = built.add(bpy.data.meshes.new(name))
    n = len(points)
    mesh.vertices.add(n)
    mesh.vertices.foreach_set("co", points.xyz.astype(np.float32).ravel())
    colour = mesh.attributes.new("color", "BYTE_COLOR", "POINT")
    rgba = np.concatenate([points.rgb / 255.0, np.ones((n, 1))], axis=1).astype(np.float32)
    colour.data.foreach_set("color_srgb", rgba.ravel())
    mesh.attributes.new("error", "FLOAT", "POINT").data.foreach_set(
        "value", points.error.astype(np.float32))
    mesh.attributes.new("track_length", "INT", "POINT").data.foreach_set(
        "value", points.track_length.astype(np.int32))
    ids = np.clip(points.ids, -(2**31), 2**31 - 1).astype(np.int32)
    mesh.attributes.new("colmap_point_id", "INT", "POINT").data.foreach_set("value", ids)
    mesh.update()
    obj = built.add(bpy.data.objects.new(name, mesh))
    collection.objects.link(obj)
    material = built.add(bpy.data.materials.new(name))
    _colour_material(material)
    try:
        context = bpy.context
        view_layer = context.view_layer if scene == context.scene else scene.view_layers[0]
        with context.temp_override(scene=scene, view_layer=view_layer,
                                   active_object=obj, object=obj, selected_objects=[obj],
                                   selected_editable_objects=[obj]):
            result = bpy.ops.object.convert(target="POINTCLOUD")
    except (RuntimeError, TypeError, AttributeError):
        result = {"CANCELLED"}
    if "FINISHED" in result and obj.type == "POINTCLOUD":
        cloud = built.add(obj.data)
        if mesh.users == 0:
            bpy.data.meshes.remove(mesh)
        if ".select_vert" in cloud.attributes:
            cloud.attributes.remove(cloud.attributes[".select_vert"])
        cloud.attributes.new("radius", "FLOAT", "POINT").data.foreach_set(
            "value", np.full(n, radius, np.float32))
    obj.data.materials.append(material)
    return obj


def _colour_material(material: bpy.types.Material) -> None:
    if material.node_tree is None:  # Blender before 5.0 makes node trees on request
        material.use_nodes = True
    nodes = material.node_tree.nodes
    bsdf = next((n for n in nodes if n.type == "BSDF_PRINCIPLED"), None)
    if bsdf is None:
        return
    attribute = nodes.new("ShaderNodeAttribute")
    attribute.attribute_name = "color"
    material.node_tree.links.new(attribute.outputs["Color"], bsdf.inputs["Base Color"])
    material.diffuse_color = (0.8, 0.8, 0.8, 1.0)


def _animated_camera(name: str, scene_data: colmap.ColmapScene, collection, scene, clip,
                     built: _Built) -> bpy.types.Object:
    """A camera keyed on frame scene.frame_start + i at image i (in name order)."""
    import mathutils

    cam = built.add(bpy.data.cameras.new(name))
    obj = built.add(bpy.data.objects.new(name, cam))
    collection.objects.link(obj)
    cam.clip_start, cam.clip_end = clip
    obj.rotation_mode = "QUATERNION"
    first = camera_to_blender(scene_data.images[0].camera, SENSOR_WIDTH)
    record_output_settings(obj, first)
    previous = None
    for i, im in enumerate(scene_data.images):
        params = camera_to_blender(im.camera, SENSOR_WIDTH)
        frame = scene.frame_start + i
        loc, rot, _scale = to_matrix(params.matrix_world).decompose()
        if previous is not None and rot.dot(previous) < 0:
            rot = mathutils.Quaternion([-v for v in rot])
        previous = rot
        obj.location, obj.rotation_quaternion = loc, rot
        set_lens(cam, params)
        obj.keyframe_insert("location", frame=frame)
        obj.keyframe_insert("rotation_quaternion", frame=frame)
        for prop in ("lens", "shift_x", "shift_y", "sensor_width"):
            cam.keyframe_insert(prop, frame=frame)
    if obj.animation_data and obj.animation_data.action:
        built.add(obj.animation_data.action)
    if cam.animation_data and cam.animation_data.action:
        built.add(cam.animation_data.action)
    sizes = {(im.camera.width, im.camera.height) for im in scene_data.images}
    obj["colmap_exact"] = len(sizes) == 1
    return obj


STAGES = ("reading", "building")  # reading: the model, photos, undistortion (a worker thread)


def import_colmap(directory: str | os.PathLike, image_folder: str = "images", *,
                  progress=None, **options) -> bpy.types.Collection:
    """Import a COLMAP model or workspace into `scene` (default: the context's); returns the
    new collection. `progress(fraction, message)` is called as the work goes. Options: those
    of `import_steps`."""
    require_modules()
    steps = import_steps(directory, image_folder, **options)
    report = progress or (lambda fraction, message: None)
    try:
        while True:
            step = next(steps)
            if step is None:
                time.sleep(WAIT_STEP)
                continue
            stage, fraction = step
            report((STAGES.index(stage) + fraction) / len(STAGES), stage)
    except StopIteration as done:
        report(1.0, "done")
        return done.value


MODULES = ("pycolmap", "OpenImageIO")  # the model, the photos
FEATURE = "Importing a COLMAP scene"


def require_modules() -> None:
    """MissingModule unless what an import needs loads: pycolmap (the model), OpenImageIO
    (the photos)."""
    for module in MODULES:
        dependencies.require(module, FEATURE)


def import_steps(directory: str | os.PathLike, image_folder: str = "images", *,
                 align: bool = True, up: str = "auto",
                 scene_size: float = colmap.DEFAULT_SCENE_SIZE,
                 cache_dir: str | os.PathLike | None = None, points: bool = True,
                 render_points: bool = False, backgrounds: bool = True,
                 animated_camera: bool = False, set_scene_camera: bool = True,
                 copy_photos: bool = True, scene: bpy.types.Scene | None = None,
                 photo_colours: bool = True, mesh_light: bool = True):
    """The import as a generator of (stage, fraction) steps (`STAGES`), or None while the
    reader works (`core.jobs.StagedJob`: the caller's thread is free), for `job_runner`; its
    return value is the new collection. The Blender-free reading (model, photos, undistortion)
    runs on a worker thread meanwhile; closing the generator stops it at its next photo and
    removes whatever was built. `photo_colours` and `mesh_light`: see `photo_scene`. The other
    arguments are those of `colmap.read_colmap`."""
    scene = scene if scene is not None else bpy.context.scene
    state = {"fraction": 0.0, "cancel": False}
    outcome: dict = {}

    def progress(fraction: float, message: str) -> None:
        if state["cancel"]:
            raise colmap.ColmapError("import cancelled")
        state["fraction"] = fraction

    def read() -> None:
        try:
            outcome["data"] = colmap.read_colmap_anywhere(
                directory, image_folder, cache_dir=cache_dir, align=align, up=up,
                scene_size=scene_size, copy_photos=copy_photos, progress=progress)
        except BaseException as error:  # handed to the main thread below
            outcome["error"] = error

    worker = threading.Thread(target=read, name="colmap-import", daemon=True)
    worker.start()
    try:
        while worker.is_alive():
            yield "reading", state["fraction"]
            yield None  # the reader works on its own thread: the caller's is free meanwhile
    finally:
        if worker.is_alive():  # closed early: stop the reader and wait for it
            state["cancel"] = True
            worker.join()
    if "error" in outcome:
        raise outcome["error"]
    built = _Built()
    try:
        collection = yield from _build(outcome["data"], scene, directory, points, render_points,
                                       backgrounds, animated_camera, set_scene_camera, built)
    except BaseException:
        built.remove_all()
        raise
    # The scene's look and light, once nothing can fail any more (undo restores them).
    if photo_colours:
        photo_scene.use_photo_colours(scene)
    if mesh_light:
        photo_scene.add_mesh_light(scene)
    hooks.make_helper_ahead(scene)  # a scene imported to be trained: F12's helper, in this run
    return collection


def _build(data: colmap.ColmapScene, scene, directory, points: bool, render_points: bool,
           backgrounds: bool, animated: bool, set_scene_camera: bool, built: _Built):
    """Generator of ("building", fraction) steps; returns the new collection."""
    root = Path(directory)
    name = root.name or "COLMAP"
    if name in ("0", "sparse") and root.parent.name:
        name = root.parent.parent.name if root.parent.name == "sparse" else root.parent.name
    collection = built.add(bpy.data.collections.new(name))
    scene.collection.children.link(collection)
    collection["colmap_transform"] = [float(v) for v in data.world_from_colmap.ravel()]
    collection["colmap_model_dir"] = str(data.model_dir)
    collection["colmap_image_dir"] = str(data.image_dir or "")
    collection["colmap_image_folder"] = data.image_folder
    collection["colmap_undistorted_dir"] = str(data.undistorted_dir or "")
    collection["colmap_alignment"] = data.alignment_info.get("method", "none")
    collection["colmap_missing"] = "\n".join(f"{k}: {v}" for k, v in data.missing.items())
    collection["colmap_warnings"] = "\n".join(data.warnings)
    # What the reader left out as non-finite, for the operator's report ("points3D: 2, ...").
    collection["colmap_dropped"] = ", ".join(f"{k}: {v}" for k, v in data.dropped.items())

    clip = _clip_range(data)
    objects = []
    for k, im in enumerate(data.images):
        params = camera_to_blender(im.camera, SENSOR_WIDTH)
        cam = built.add(bpy.data.cameras.new(im.name))
        cam.clip_start, cam.clip_end = clip
        obj = built.add(bpy.data.objects.new(im.name, cam))
        collection.objects.link(obj)
        set_camera(obj, params)
        obj["colmap_image_name"] = im.name
        obj["colmap_image_id"] = im.image_id
        obj["colmap_camera_id"] = im.camera_id
        obj["colmap_photo"] = str(im.path or "")
        record_output_settings(obj, params)
        if backgrounds and im.path is not None:
            before = len(bpy.data.images)
            image = bpy.data.images.load(str(im.path), check_existing=True)
            if len(bpy.data.images) > before:  # new, not the user's own
                built.add(image)
            cam.show_background_images = True
            background = cam.background_images.new()
            background.image = image
            background.frame_method = "STRETCH"
            background.alpha = 1.0
        objects.append(obj)
        if k % 16 == 0:
            yield "building", 0.7 * (k + 1) / len(data.images)

    if points and len(data.points):
        size = np.median([np.linalg.norm(im.camera.centre - data.points.xyz.mean(axis=0))
                          for im in data.images])
        cloud = _points_object(f"{collection.name} points", data.points, 0.002 * float(size),
                               collection, scene, built)
        cloud.hide_render = not render_points  # a guide for the viewport, not part of a frame
    yield "building", 0.8
    if animated:
        _animated_camera(f"{collection.name} sequence", data, collection, scene, clip, built)
    if set_scene_camera and objects:
        scene.camera = objects[0]
        apply_camera_resolution(scene, objects[0])
    return collection


# -- operators ---------------------------------------------------------------------------------

class SPLAT_OT_import_colmap(JobOperator, bpy.types.Operator):
    """Import a COLMAP (or GLOMAP) reconstruction: cameras, photos, sparse points"""

    bl_idname = "splat.import_colmap"
    bl_label = "Import COLMAP Scene"
    bl_options = {"REGISTER", "UNDO"}

    directory: StringProperty(name="Folder", subtype="DIR_PATH",
                              description="COLMAP workspace (with sparse/0) or model folder")
    filter_folder: BoolProperty(default=True, options={"HIDDEN"})
    image_folder: StringProperty(
        name="Image Folder", default="images",
        description="Photos beside the model: images, images_2, images_4, images_8 (may hold "
                    "only some photos), or an absolute path")
    align: BoolProperty(name="Align", default=True,
                        description="Stand the scene upright (Z up), centre and scale it")
    up_axis: EnumProperty(
        name="Up From", default="AUTO",
        items=[("AUTO", "Cameras and Ground",
                "Cameras' horizon, refined by the points' ground plane"),
               ("CAMERAS", "Camera Up Vectors", "Mean of the cameras' up vectors")])
    scene_size: FloatProperty(name="Scene Size", default=colmap.DEFAULT_SCENE_SIZE, min=0.001,
                              description="Median camera distance from the centre after aligning")
    points: BoolProperty(name="Sparse Points", default=True)
    render_points: BoolProperty(name="Render Points", default=False,
                                description="Show the sparse points in final renders too (off: "
                                            "viewport only)")
    backgrounds: BoolProperty(name="Photo Backgrounds", default=True,
                              description="Show each photo as its camera's background")
    animated_camera: BoolProperty(name="Animated Camera", default=False,
                                  description="A camera that follows the images, a frame each")
    photo_colours: BoolProperty(
        name="Photo Colours", default=True,
        description="Set the scene's view transform to Standard, so renders show splats and "
                    "photos with the photos' colours (AgX, Blender's default, washes them out)")
    mesh_light: BoolProperty(
        name="Light for Meshes", default=True,
        description="If the scene has no World, add one that lights meshes with a uniform white "
                    "light but looks black to the camera: meshes made from the splats (Convert "
                    "to Mesh) render with their colours; splats carry their own light")
    cache_dir: StringProperty(name="Cache Folder", subtype="DIR_PATH", default="",
                              description="Where undistorted photos go (empty: beside the "
                                          "input if writable, else a user cache folder)")

    interactive: BoolProperty(default=False, options={"HIDDEN", "SKIP_SAVE"},
                              description="Read on a worker thread with a modal timer (set by "
                                          "invoke; scripts get a blocking run)")

    needs = (MODULES, FEATURE)
    poll = classmethod(dependencies.poll_needs)
    invoke = JobOperator.invoke_file_browser

    def execute(self, context):
        try:
            require_modules()
        except dependencies.MissingModule as error:
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}
        steps = import_steps(
            self.directory, self.image_folder, align=self.align, up=self.up_axis.lower(),
            scene_size=self.scene_size, cache_dir=self.cache_dir or None, points=self.points,
            render_points=self.render_points, backgrounds=self.backgrounds,
            animated_camera=self.animated_camera, scene=context.scene,
            photo_colours=self.photo_colours, mesh_light=self.mesh_light)
        image_folder = self.image_folder

        def finish(running, write):
            job = running.job
            if job.error is not None:
                return "ERROR", str(job.error), None
            collection = job.result
            if collection is None:
                return "WARNING", "COLMAP import cancelled: nothing changed", None
            for warning in collection["colmap_warnings"].splitlines():
                self.report({"WARNING"}, warning)
            if collection["colmap_dropped"]:
                self.report({"WARNING"}, f"left out as non-finite (NaN or Inf) in the model: "
                                         f"{collection['colmap_dropped']}")
            missing = collection["colmap_missing"].splitlines()
            cameras = sum(1 for o in collection.objects if "colmap_image_name" in o)
            if missing:
                shown = ", ".join(line.split(":")[0] for line in missing[:5])
                more = f" and {len(missing) - 5} more" if len(missing) > 5 else ""
                return ("WARNING", f"{len(missing)} of {cameras} photos missing or unusable in "
                                   f"{image_folder} ({shown}{more}): their cameras have no "
                                   f"photo", None)
            return "INFO", f"imported {cameras} cameras into '{collection.name}'", None

        key = f"colmap:{Path(self.directory).resolve()}"
        return self.run_job(context, OperatorJob(key, "Importing COLMAP",
                                                 StagedJob(steps, STAGES), finish))


class SPLAT_OT_colmap_set_camera(bpy.types.Operator):
    """Make the active camera the scene camera, with its photo's resolution and pixel aspect"""

    bl_idname = "splat.colmap_set_camera"
    bl_label = "Set COLMAP Camera"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        obj = context.active_object
        return obj is not None and obj.type == "CAMERA"

    def execute(self, context):
        context.scene.camera = context.active_object
        apply_camera_resolution(context.scene, context.active_object)
        return {"FINISHED"}


def _menu_import(self, context):
    self.layout.operator(SPLAT_OT_import_colmap.bl_idname, text="COLMAP Scene (cameras, points)")


_CLASSES = (SPLAT_OT_import_colmap, SPLAT_OT_colmap_set_camera)


_register, _unregister = module_registration(
    _CLASSES, handlers=_HANDLERS,
    menus=[("TOPBAR_MT_file_import", _menu_import), ("RENDER_PT_format", _draw_switch)])


def register() -> None:
    if SWITCH not in bpy.types.Scene.bl_rna.properties:
        setattr(bpy.types.Scene, SWITCH, BoolProperty(
            name="Use COLMAP Camera Output", default=True,
            description="Set the resolution and pixel aspect from each imported COLMAP camera's "
                        "photo when it becomes the scene camera (also through markers) or a "
                        "render starts"))
    _register()
    _subscribe()


def unregister() -> None:
    bpy.msgbus.clear_by_owner(_MSGBUS_OWNER)
    _unregister()
    if SWITCH in bpy.types.Scene.bl_rna.properties:
        delattr(bpy.types.Scene, SWITCH)
