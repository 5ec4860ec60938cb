"""Splats to a textured mesh: `convert_to_mesh(obj, ...)` and `bpy.ops.splat.convert_to_mesh`.

Pipeline (the numpy parts are in `addon.core.mesh.surface` and `addon.core.mesh.texture`):
  1. gather the splat object's world-space Gaussians (modifiers, transform applied);
  2. cameras: the COLMAP cameras the object was trained from (`cameras='COLMAP'`; 'AUTO' uses
     them when found), else `view_count` cameras on a Fibonacci sphere framing the splats
     ('SPHERE'); each renders at most `view_size` pixels a side (colour, alpha, depth);
  3. TSDF fusion on a grid of `resolution` cells along the longest side, surface nets,
     small floating pieces dropped;
  4. Blender's Decimate modifier (collapse, triangulated) down to `max_triangles`;
  5. xatlas UV atlas, texture of `texture_size`^2 baked from the same renders, seams filled;
  6. a new mesh object in world space, UV map "UVMap", an 8-bit sRGB image packed into the
     .blend, and a Principled BSDF material with the image as Base Color (roughness 0.8,
     specular 0.2: the splats' colour is the lit appearance, so a dull surface that Blender
     lights again looks closest; it renders and shadows in Cycles and EEVEE alike).

Proxy (`proxy=True`), for composing meshes with a captured scene:
  - Cycles shadow catcher (`is_shadow_catcher`): the proxy itself renders transparent, only the
    shadows modelled objects cast onto it show. In final renders the compositor bridge turns
    on Cycles' Shadow Catcher pass and multiplies the caught shadow over the splat composite
    (`compositor_bridge.needs_shadow_pass`, `addon.core.render.composite.apply_shadow_catcher`).
    It stays visible to camera rays, because Cycles shows caught shadows only on camera-visible
    catchers; it is hidden from glossy and transmission rays (so it never
    appears in reflections) but casts shadows (`visible_shadow`) and is diffusely lit;
  - a Collision modifier (physics: cloth, particles, soft bodies collide with it);
  - `display_type = 'WIRE'` in the viewport, and the custom property `splat_proxy_of` (the splat
    object). Every converted mesh has `splat_source` (the splat object) too.
The issue asked for "hidden from camera rays"; with Cycles that would hide the caught shadows as
well, so the shadow catcher is the camera-side half of "hidden".

Progress and cancel: `progress(stage, fraction)` and `cancel() -> bool` are called between
views and stages; a cancelled conversion raises `Cancelled` and leaves no datablock behind.
The operator runs the same steps through `job_runner` (`StagedJob`: on the main thread, since
it makes datablocks): blocking from scripts and in background mode (a line per stage in the
terminal), and from the UI a little on every timer tick (status bar progress, Esc cancels).
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Callable, Iterator

import bpy
import numpy as np
from bpy.props import BoolProperty, EnumProperty, IntProperty

from ..core.cameras import Camera
from ..core.mesh import surface, texture
from ..core.mesh.surface import Cancelled
from ..core.jobs import StagedJob
from . import dependencies
from .sources import gather
from .threads import scene_threads
from .blender_splats import any_splats
from .camera_adapter import camera_of
from .job_runner import JobOperator, OperatorJob, wants_background
from .registration import module_registration

MODULE = "xatlas"  # the UV atlas
FEATURE = "Converting splats to a mesh (its UV atlas)"

CAMERA_MODES = ("AUTO", "COLMAP", "SPHERE")
SOURCE_KEY = "splat_source"
PROXY_KEY = "splat_proxy_of"
TRAINED_OBJECT_KEY = "splat_object"  # what training sets on its COLMAP collection


class ConversionError(ValueError):
    """Bad input: not a splat object, no splats, no COLMAP cameras, bad settings."""


# -- cameras -------------------------------------------------------------------------------------

def colmap_camera_objects(obj) -> list:
    """Camera objects of the COLMAP collection `obj` was trained from (the collection whose
    `splat_object` is `obj`, else a collection holding `obj` that has imported cameras)."""
    candidates = [c for c in bpy.data.collections if c.get(TRAINED_OBJECT_KEY) == obj]
    candidates += [c for c in obj.users_collection if c not in candidates]
    for collection in candidates:
        cams = [o for o in collection.all_objects
                if o.type == "CAMERA" and "colmap_image_name" in o]
        if cams:
            return sorted(cams, key=lambda o: o.name)
    return []


def camera_of_object(camera_obj, scene, max_size: int) -> Camera:
    """The pinhole camera of a Blender camera object (its COLMAP resolution when imported,
    else the scene's), scaled down to at most `max_size` pixels a side."""
    full = camera_of(camera_obj, scene.render, use_recorded=True)
    s = min(1.0, max_size / max(full.width, full.height))
    w, h = max(1, round(full.width * s)), max(1, round(full.height * s))
    sx, sy = w / full.width, h / full.height
    return replace(full, fx=full.fx * sx, fy=full.fy * sy, cx=full.cx * sx, cy=full.cy * sy,
                   width=w, height=h)


def choose_cameras(obj, mode: str, scene, view_size: int) -> list[Camera] | None:
    """COLMAP cameras for 'COLMAP' (an error when there are none) and 'AUTO' (when there are);
    None means: a Fibonacci sphere."""
    if mode not in CAMERA_MODES:
        raise ConversionError(f"cameras must be one of {CAMERA_MODES}, got {mode!r}")
    if mode == "SPHERE":
        return None
    objects = colmap_camera_objects(obj)
    if not objects:
        if mode == "COLMAP":
            raise ConversionError(f"'{obj.name}' has no COLMAP cameras (it was not trained from "
                                  "an imported COLMAP scene); use cameras='SPHERE'")
        return None
    return [camera_of_object(o, scene, view_size) for o in objects]


# -- the job -------------------------------------------------------------------------------------

def _check(obj, resolution, max_triangles, texture_size) -> None:
    if obj is None or not any_splats.is_splat_source(obj):
        name = "nothing" if obj is None else f"'{obj.name}'"
        raise ConversionError(f"{name} is not a splat object")
    if not 8 <= resolution <= 1024:
        raise ConversionError(f"resolution must be 8..1024, got {resolution}")
    if max_triangles < 4:
        raise ConversionError(f"max_triangles must be at least 4, got {max_triangles}")
    if not 16 <= texture_size <= 16384:
        raise ConversionError(f"texture_size must be 16..16384, got {texture_size}")
    try:
        dependencies.require(MODULE, FEATURE)
    except dependencies.MissingModule as error:
        raise ConversionError(str(error)) from error


def _decimate(vertices: np.ndarray, faces: np.ndarray, max_triangles: int
              ) -> tuple[np.ndarray, np.ndarray]:
    """Blender's Decimate modifier (collapse, triangulated) down to `max_triangles`."""
    if len(faces) <= max_triangles:
        return vertices, faces
    mesh = _new_mesh("splat_decimate_tmp", vertices, faces)
    obj = bpy.data.objects.new("splat_decimate_tmp", mesh)
    bpy.context.scene.collection.objects.link(obj)
    result = None
    try:
        modifier = obj.modifiers.new("Decimate", "DECIMATE")
        modifier.decimate_type = "COLLAPSE"
        modifier.use_collapse_triangulate = True
        ratio = max_triangles / len(faces)
        for _ in range(4):
            modifier.ratio = ratio
            depsgraph = bpy.context.evaluated_depsgraph_get()
            result = bpy.data.meshes.new_from_object(obj.evaluated_get(depsgraph))
            v, f = _mesh_arrays(result)
            bpy.data.meshes.remove(result)
            result = None
            if len(f) <= max_triangles:
                return v, f
            ratio *= 0.97 * max_triangles / len(f)
        return v, f
    finally:
        if result is not None:
            bpy.data.meshes.remove(result)
        bpy.data.objects.remove(obj)
        bpy.data.meshes.remove(mesh)


def _mesh_arrays(mesh) -> tuple[np.ndarray, np.ndarray]:
    mesh.calc_loop_triangles()
    v = np.empty(len(mesh.vertices) * 3, np.float32)
    mesh.vertices.foreach_get("co", v)
    f = np.empty(len(mesh.loop_triangles) * 3, np.int32)
    mesh.loop_triangles.foreach_get("vertices", f)
    return v.reshape(-1, 3).astype(np.float64), f.reshape(-1, 3).astype(np.int64)


def _new_mesh(name: str, vertices: np.ndarray, faces: np.ndarray, corner_uvs=None):
    mesh = bpy.data.meshes.new(name)
    try:
        mesh.vertices.add(len(vertices))
        mesh.vertices.foreach_set("co", np.asarray(vertices, np.float32).ravel())
        mesh.loops.add(3 * len(faces))
        mesh.loops.foreach_set("vertex_index", np.asarray(faces, np.int32).ravel())
        mesh.polygons.add(len(faces))
        mesh.polygons.foreach_set("loop_start", np.arange(0, 3 * len(faces), 3, dtype=np.int32))
        if corner_uvs is not None:
            uv = mesh.uv_layers.new(name="UVMap")
            uv.data.foreach_set("uv", np.asarray(corner_uvs, np.float32).ravel())
        mesh.update(calc_edges=True)
        mesh.validate(clean_customdata=False)
    except BaseException:
        bpy.data.meshes.remove(mesh)
        raise
    return mesh


def _material(name: str, image) -> bpy.types.Material:
    material = bpy.data.materials.new(name)
    if bpy.app.version < (5, 0, 0):  # always node based from 5.0 (use_nodes is deprecated)
        material.use_nodes = True
    nodes, links = material.node_tree.nodes, material.node_tree.links
    bsdf = next(n for n in nodes if n.type == "BSDF_PRINCIPLED")
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = image
    tex.interpolation = "Linear"
    tex.extension = "EXTEND"
    tex.location = (-400, 200)
    links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    bsdf.inputs["Roughness"].default_value = 0.8
    if "Specular IOR Level" in bsdf.inputs:
        bsdf.inputs["Specular IOR Level"].default_value = 0.2
    return material


def _image(name: str, texture: np.ndarray) -> bpy.types.Image:
    size = texture.shape[0]
    image = bpy.data.images.new(name, size, size, alpha=False, float_buffer=False)
    try:
        image.colorspace_settings.name = "sRGB"
        rgba = np.ones((size, size, 4), np.float32)
        rgba[..., :3] = texture  # display sRGB values, stored as bytes (no conversion)
        image.pixels.foreach_set(rgba.ravel())
        image.file_format = "PNG"
        image.pack()
    except BaseException:
        bpy.data.images.remove(image)
        raise
    return image


def convert_job(obj, *, resolution: int = 128, max_triangles: int = 100_000,
                texture_size: int = 1024, cameras: str = "AUTO", proxy: bool = False,
                view_count: int = 48, view_size: int = 192, name: str | None = None,
                stats: dict | None = None) -> Iterator[tuple[str, float]]:
    """The conversion as a generator of (stage, fraction) steps; its return value (the
    StopIteration value) is the new object. Closing it early leaves nothing behind."""
    _check(obj, resolution, max_triangles, texture_size)
    stats = {} if stats is None else stats
    t0 = time.perf_counter()
    depsgraph = bpy.context.evaluated_depsgraph_get()
    gathered = gather.gather(depsgraph, objects=[obj], use_cache=False,
                             include_blender_rendered=True)
    gaussians = gathered.gaussians
    if len(gaussians) == 0:
        raise ConversionError(f"'{obj.name}' has no visible splats")
    cams = choose_cameras(obj, cameras, depsgraph.scene, view_size)
    bounds = surface.splat_bounds(gaussians)
    if cams is None:
        fov = 50.0
        centre = 0.5 * (bounds[0] + bounds[1])
        cams = surface.fibonacci_cameras(centre, surface.framing_radius(bounds, fov),
                                         view_count, view_size, view_size, fov)
    stats["cameras"] = len(cams)
    yield "render", 0.0
    views = []
    threads = scene_threads(depsgraph.scene, beside_ui=False)  # on the main thread: all of them
    for i, cam in enumerate(cams):
        views.extend(surface.render_views(gaussians, [cam], antialiased=gathered.antialiased,
                                          threads=threads))
        yield "render", (i + 1) / len(cams)
    stats["render_s"] = time.perf_counter() - t0
    yield "fuse", 0.0  # each stage is announced as it starts (a headless line says what runs)
    t = time.perf_counter()
    volume = surface.fuse_tsdf([v.depth for v in views], [v.alpha for v in views], cams,
                               bounds, resolution)
    yield "fuse", 1.0
    stats["fuse_s"] = time.perf_counter() - t
    yield "extract", 0.0
    t = time.perf_counter()
    vertices, faces = surface.extract_surface(volume)
    vertices, faces = surface.largest_components(vertices, faces, min_fraction=0.01)
    if not len(faces):
        raise ConversionError(f"no surface found in '{obj.name}' (try another resolution or "
                              "cameras)")
    stats["extract_s"] = time.perf_counter() - t
    stats["extracted_triangles"] = len(faces)
    yield "extract", 1.0
    yield "decimate", 0.0
    t = time.perf_counter()
    vertices, faces = _decimate(vertices, faces, max_triangles)
    stats["decimate_s"] = time.perf_counter() - t
    yield "decimate", 1.0
    yield "unwrap", 0.0
    t = time.perf_counter()
    corner_uvs = texture.unwrap(vertices, faces, texture_size)
    stats["unwrap_s"] = time.perf_counter() - t
    yield "unwrap", 1.0
    yield "texture", 0.0
    t = time.perf_counter()
    baked = texture.project_texture(vertices, faces, views, texture_size,
                                    tolerance=2.0 * volume.grid.voxel, corner_uvs=corner_uvs)
    stats["texture_s"] = time.perf_counter() - t
    stats["coverage"] = baked.coverage
    yield "texture", 1.0

    # Everything below creates datablocks: one step, cleaned up on failure.
    name = name or f"{obj.name} Mesh"
    created = []
    try:
        mesh = _new_mesh(name, vertices, faces, corner_uvs)
        created.append(("meshes", mesh))
        image = _image(f"{name} Texture", baked.image)
        created.append(("images", image))
        material = _material(f"{name} Material", image)
        created.append(("materials", material))
        mesh.materials.append(material)
        new = bpy.data.objects.new(name, mesh)
        created.append(("objects", new))
        new[SOURCE_KEY] = obj
        new["splat_mesh_resolution"] = int(resolution)
        if proxy:
            make_proxy(new, obj)
        collection = obj.users_collection[0] if obj.users_collection else \
            bpy.context.scene.collection
        collection.objects.link(new)
    except BaseException:
        for kind, block in reversed(created):
            getattr(bpy.data, kind).remove(block)
        raise
    stats["triangles"] = len(faces)
    stats["vertices"] = len(vertices)
    stats["texture_size"] = texture_size
    stats["total_s"] = time.perf_counter() - t0
    return new


def make_proxy(mesh_obj, splat_obj) -> None:
    """Mark a converted mesh as its splat object's proxy (see the module notes)."""
    mesh_obj.is_shadow_catcher = True
    mesh_obj.visible_camera = True  # a catcher shows caught shadows only to camera rays
    mesh_obj.visible_shadow = True
    mesh_obj.visible_glossy = False
    mesh_obj.visible_transmission = False
    mesh_obj.display_type = "WIRE"
    if not any(m.type == "COLLISION" for m in mesh_obj.modifiers):
        mesh_obj.modifiers.new("Collision", "COLLISION")
    mesh_obj[PROXY_KEY] = splat_obj


def convert_to_mesh(obj, resolution: int = 128, max_triangles: int = 100_000,
                    texture_size: int = 1024, cameras: str = "AUTO", proxy: bool = False, *,
                    view_count: int = 48, view_size: int = 192,
                    progress: Callable[[str, float], None] | None = None,
                    cancel: Callable[[], bool] | None = None, stats: dict | None = None):
    """Convert splat object `obj` to a textured mesh object (see the module notes); returns the
    new object, linked next to `obj`. Raises ConversionError on bad input, Cancelled when
    `cancel()` says so (nothing is left behind)."""
    job = convert_job(obj, resolution=resolution, max_triangles=max_triangles,
                      texture_size=texture_size, cameras=cameras, proxy=proxy,
                      view_count=view_count, view_size=view_size, stats=stats)
    try:
        while True:
            if cancel is not None and cancel():
                job.close()
                raise Cancelled()
            stage, fraction = next(job)
            if progress is not None:
                progress(stage, fraction)
    except StopIteration as done:
        return done.value


STAGES = ("render", "fuse", "extract", "decimate", "unwrap", "texture")


class SPLAT_OT_convert_to_mesh(JobOperator, bpy.types.Operator):
    """Convert the active splat object to a textured triangle mesh (surface from fused depth,
    xatlas UVs, texture baked from splat renders)"""

    bl_idname = "splat.convert_to_mesh"
    bl_label = "Convert Splats to Mesh"
    bl_options = {"REGISTER", "UNDO"}

    resolution: IntProperty(name="Resolution", default=128, min=8, max=1024,
                            description="Volume cells along the longest side of the splats")
    max_triangles: IntProperty(name="Triangle Budget", default=100_000, min=4,
                               description="Decimate to at most this many triangles")
    texture_size: IntProperty(name="Texture Size", default=1024, min=16, max=16384,
                              description="Width and height of the baked colour texture")
    cameras: EnumProperty(name="Cameras", default="AUTO", items=(
        ("AUTO", "Auto", "The COLMAP cameras the splats were trained from, else a sphere"),
        ("COLMAP", "COLMAP", "The imported COLMAP cameras the splats were trained from"),
        ("SPHERE", "Sphere", "Cameras on a sphere around the splats")))
    view_count: IntProperty(name="Sphere Views", default=48, min=4, max=1024,
                            description="Cameras on the sphere")
    view_size: IntProperty(name="View Size", default=192, min=16, max=4096,
                           description="Largest side of each depth render, in pixels")
    proxy: BoolProperty(name="Proxy", default=False,
                        description="Shadow catcher and collider for its splat object")

    @classmethod
    def poll(cls, context):
        return dependencies.poll_unavailable(cls, MODULE, FEATURE) and context.mode == "OBJECT"

    def _kwargs(self):
        return dict(resolution=self.resolution, max_triangles=self.max_triangles,
                    texture_size=self.texture_size, cameras=self.cameras, proxy=self.proxy,
                    view_count=self.view_count, view_size=self.view_size)

    def invoke(self, context, event):
        self.interactive = wants_background(context)
        return self.execute(context)

    def execute(self, context):
        obj = context.active_object
        stats: dict = {}
        try:
            _check(obj, self.resolution, self.max_triangles, self.texture_size)
            steps = convert_job(obj, stats=stats, **self._kwargs())
        except ConversionError as error:
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}

        def finish(running, write):
            job = running.job
            if job.error is not None:
                return "ERROR", f"Conversion failed: {job.error}", None
            if job.result is None:
                return "WARNING", "Conversion cancelled: nothing changed", None
            new = job.result
            return "INFO", (f"'{new.name}': {stats['triangles']} triangles, "
                            f"{self.texture_size}px texture, {stats['total_s']:.1f} s"), new

        return self.run_job(context, OperatorJob(f"mesh:{obj.name}", "Converting to mesh",
                                                 StagedJob(steps, STAGES), finish))


def _menu(self, context):
    self.layout.operator(SPLAT_OT_convert_to_mesh.bl_idname, text="Convert Splats to Mesh")


CLASSES = (SPLAT_OT_convert_to_mesh,)


register, unregister = module_registration(CLASSES, menus=[("VIEW3D_MT_object_convert", _menu)])
