"""Final renders with splats: the render engine behind the compositor bridge, and the handlers.

How a frame is made (see `compositor_bridge` for why it works this way):

1. `render_init`: for a scene with splat objects (and Properties > Render > Gaussian Splats >
   "Composite Splats" on), make sure the compositor bridge is set up and the bridged view layer
   has its Depth pass.
2. The scene's engine (Cycles, EEVEE, Workbench...) renders the meshes. While it prepares, Blender
   evaluates the engine's own render depsgraph for the frame and calls `frame_change_post` with
   it: `_on_frame_change` gathers the splats from *that* depsgraph (render visibility, render
   modifier levels, animation at the frame) and the camera Blender renders with.
3. The compositor asks for the helper scene: `SplatRenderEngine.render` reads the meshes' colour
   (premultiplied scene-linear) and planar depth from the Render Result, composes the splats with
   them exactly (`addon.core.composite.compose`) and returns the composite. The compositor hands
   it on to the Render Result (the Image Editor shows it), to the file or movie Blender writes,
   and to any compositor nodes downstream.
4. `render_write`: for multilayer EXR output, the splat layer's own colour, alpha and depth are
   added to the written file as the layer "Splats" (passes Combined and Depth).

Reading the render: `Image.save_render` of the Render Result to an uncompressed float
multilayer EXR in a private temporary folder (the output format is switched for that one call
and put back). A command-line render (`blender -b file.blend -a`) has no "Render Result" image
unless the file brought one; then the scene's render cache (`render.use_render_cache`, switched
on for the render and back off after it) writes that EXR and it is read from Blender's cache
path.

The engine also renders on its own: with "Gaussian Splats" as the scene's render engine (the
"Render splats only" button), only the splats are rendered, over the world colour or over
transparency, with no mesh render at all.
"""

from __future__ import annotations

import atexit
import contextlib
import hashlib
import os
import shutil
import tempfile
import time
import traceback
from dataclasses import dataclass, field

import bpy
import numpy as np
from bpy.app.handlers import persistent

from ..core import exr_layers, exr_scanlines
from ..core.cameras import Camera
from ..core.composite import (FAR, Region, apply_shadow_catcher, compose, embed,
                              render_region, splat_layer)
from ..core.gaussians import Gaussians
from . import compositor_bridge as bridge
from . import dependencies, gather
from .camera_adapter import camera_of, frame_size
from .compositor_bridge import ENGINE_ID


@dataclass
class FrameSplats:
    """What one frame renders: gathered from the render's own depsgraph."""

    scene: str
    view_layer: str
    frame: int
    gaussians: Gaussians
    camera: Camera | None        # the full frame; None: no perspective camera (nothing to draw)
    antialiased: bool
    color_space: str
    sh_degree: int
    near: float
    threads: int
    gather_ms: float
    warnings: list[str] = field(default_factory=list)

    def render_options(self) -> dict:
        return dict(color_space=self.color_space, antialiased=self.antialiased, near=self.near,
                    sh_degree=self.sh_degree, threads=self.threads)


class _State:
    def __init__(self) -> None:
        self.scene: str | None = None          # the scene being rendered (render_init..complete)
        self.frames: dict[tuple[str, str], FrameSplats] = {}
        self.frame_start_ns = 0
        self.pending_passes: dict[str, tuple[int, object]] = {}
        self.cache_restore: dict[str, bool] = {}
        self.force_cache_file = False          # tests: read the render through the cache file
        self.errors: list[str] = []            # why the current (or last) render failed
        self.failed_frames: set[int] = set()   # frames whose written files must not stay
        self.camera_restore: dict[str, object] = {}  # scenes whose camera a failure cleared


_state = _State()
last_stats: dict[str, float] = {}       # the last composed frame: timings (ms) and counts
_temp_dir: str | None = None


# ------------------------------------------------------------------------------------ helpers

def settings_of(scene):
    return scene.splat_render


def render_border(render) -> tuple[float, float, float, float] | None:
    if not render.use_border:
        return None
    return (render.border_min_x, render.border_max_x, render.border_min_y, render.border_max_y)


def capture_frame(scene, depsgraph) -> FrameSplats:
    """Gather the splats and the camera a render depsgraph shows (see the module docstring)."""
    settings = settings_of(scene)
    start = time.perf_counter()
    result = gather.gather(depsgraph)
    warnings = list(result.warnings)
    camera = None
    camera_obj = depsgraph.scene.camera
    if camera_obj is None:
        warnings.append("the scene has no camera")
    else:
        camera_obj = camera_obj.evaluated_get(depsgraph)
        if camera_obj.type != "CAMERA" or camera_obj.data.type != "PERSP":
            warnings.append("splats render through perspective cameras only: "
                            f"{camera_obj.name!r} is not one, so no splats are drawn")
        else:
            camera = camera_of(camera_obj, depsgraph.scene_eval.render)
    antialiased = {"OBJECT": result.antialiased, "ON": True, "OFF": False}[settings.antialiased]
    spaces = {b.color_space for b in result.batches}
    if len(spaces) > 1:
        warnings.append("splat objects disagree on the colour space: composing in sRGB")
    color_space = "LINEAR" if spaces == {"LINEAR"} else "SRGB"
    gaussians = result.gaussians
    return FrameSplats(scene.name, depsgraph.view_layer.name, scene.frame_current, gaussians,
                       camera, antialiased, color_space,
                       min(settings.sh_degree, gaussians.degree), settings.near, settings.threads,
                       1000 * (time.perf_counter() - start), warnings)


def _private_dir() -> str:
    global _temp_dir
    if _temp_dir is None or not os.path.isdir(_temp_dir):
        base = "/dev/shm" if os.path.isdir("/dev/shm") and os.access("/dev/shm", os.W_OK) else None
        _temp_dir = tempfile.mkdtemp(prefix="splat-render-", dir=base)
    return _temp_dir


@atexit.register
def _remove_private_dir() -> None:
    if _temp_dir is not None:
        shutil.rmtree(_temp_dir, ignore_errors=True)


_FORMAT_KEYS = ("media_type", "file_format", "color_mode", "color_depth", "exr_codec",
                "use_preview", "use_exr_interleave", "color_management", "quality", "compression")


@contextlib.contextmanager
def _float_exr_output(scene):
    """Switch the scene's output format to uncompressed float multilayer EXR, then back."""
    settings = scene.render.image_settings
    saved = [(key, getattr(settings, key)) for key in _FORMAT_KEYS if hasattr(settings, key)]
    # Blender 5.0 cannot write a multi-part EXR for non-square pixels (its parts disagree on
    # 'pixelAspectRatio'); the pixels are the same either way.
    aspect = (scene.render.pixel_aspect_x, scene.render.pixel_aspect_y)
    try:
        scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
        if hasattr(settings, "media_type"):
            settings.media_type = "MULTI_LAYER_IMAGE"
        else:  # Blender 4.x
            settings.file_format = "OPEN_EXR_MULTILAYER"
        settings.color_depth = "32"
        settings.exr_codec = "NONE"
        if hasattr(settings, "color_management"):
            settings.color_management = "FOLLOW_SCENE"
        yield
    finally:
        scene.render.pixel_aspect_x, scene.render.pixel_aspect_y = aspect
        for key, value in saved:
            with contextlib.suppress(TypeError, AttributeError, ValueError):
                setattr(settings, key, value)


def render_result_image():
    return next((image for image in bpy.data.images if image.type == "RENDER_RESULT"), None)


def cache_file_path(scene) -> str:
    """Where Blender's render cache (`render.use_render_cache`) writes a scene's render
    (`render_result_exr_file_cache_path` in Blender's render_result.cc)."""
    blend = bpy.data.filepath
    tempdir_base = os.path.dirname(os.path.normpath(bpy.app.tempdir))
    if blend:
        dirname, filename = os.path.split(blend)
        filename = os.path.splitext(filename)[0]
        digest = hashlib.md5(blend.encode()).hexdigest()
    else:
        dirname, filename, digest = tempdir_base, "UNSAVED", "0" * 32
    root = bpy.context.preferences.filepaths.render_cache_directory or tempdir_base
    if root.startswith("//"):
        root = os.path.join(dirname, root[2:])
    return os.path.join(root, f"cached_RR_{filename}_{scene.name}_{digest}.exr")


def read_render_layer(scene, layer: str) -> tuple[np.ndarray, np.ndarray, dict]:
    """The colour (H, W, 4 premultiplied scene-linear) and planar depth (H, W) the scene's
    engine rendered for view layer `layer`, rows top to bottom, read while the render runs;
    and timings (ms), with "layer": the view layer read (another one if `layer` was not
    rendered)."""
    timings = {}
    start = time.perf_counter()
    image = render_result_image()
    if image is None or _state.force_cache_file:
        path = cache_file_path(scene)
        if not os.path.exists(path) or os.stat(path).st_mtime_ns < _state.frame_start_ns - 50_000_000:
            raise RuntimeError(
                f"cannot read the render: there is no Render Result image and no fresh render "
                f"cache file at {path}")
    else:
        path = os.path.join(_private_dir(), f"render-{abs(hash(scene.name))}.exr")
        with _float_exr_output(scene):
            image.save_render(path, scene=scene)
    timings["save_ms"] = 1000 * (time.perf_counter() - start)
    start = time.perf_counter()
    channels = exr_scanlines.read_channels(path)  # no OpenImageIO: Blender's Python may lack it
    timings["read_ms"] = 1000 * (time.perf_counter() - start)
    rgba = exr_layers.find_pass(channels, layer, "Combined", "RGBA")
    if rgba is None:  # e.g. "Render Single Layer" with another layer active: use what rendered
        layers = sorted({name[:-len(".Combined.R")] for name in channels
                         if name.endswith(".Combined.R") and not name.startswith("Composite.")})
        if not layers:
            raise RuntimeError(f"the render has no Combined pass for view layer {layer!r}")
        print(f"Gaussian splats: view layer {layer!r} was not rendered; composing with "
              f"{layers[0]!r}")
        layer = layers[0]
        rgba = exr_layers.find_pass(channels, layer, "Combined", "RGBA")
    depth = exr_layers.find_pass(channels, layer, "Depth", "Z")
    if depth is None:
        print(f"Gaussian splats: view layer {layer!r} has no Depth pass; splats are drawn in "
              f"front of every mesh (enable View Layer > Passes > Data > Z)")
        depth = np.full(rgba.shape[:2], FAR, np.float32)
    else:
        depth = depth[..., 0]
    timings["layer"] = layer
    # Cycles' "Shadow Catcher" pass (on when the scene has shadow catchers, e.g. splat proxies:
    # `compositor_bridge.ensure_bridge`): the factor the composite is darkened by.
    timings["shadow"] = exr_layers.find_pass(channels, layer, "Shadow Catcher", "RGB")
    return np.ascontiguousarray(rgba), np.ascontiguousarray(depth), timings


def world_colour(scene) -> np.ndarray:
    """The world's background as a flat scene-linear colour (its Background node's colour times
    its strength when that is not driven by other nodes, else the world colour); black without
    a world."""
    world = scene.world
    if world is None:
        return np.zeros(3, np.float32)
    tree = world.node_tree if getattr(world, "use_nodes", True) else None
    if tree is not None:
        for node in tree.nodes:
            if node.bl_idname == "ShaderNodeBackground" and any(
                    link.from_node == node for link in tree.links):
                colour, strength = node.inputs["Color"], node.inputs["Strength"]
                if not colour.is_linked and not strength.is_linked:
                    return np.array(colour.default_value[:3], np.float32) * strength.default_value
    return np.array(world.color[:3], np.float32)


def _frame_target(size: tuple[int, int], full: tuple[int, int], region: Region) -> Region:
    """Which part of the frame a render result of `size` (width, height) covers."""
    if size == full:
        return Region(0, 0, *full)
    if size == (region.width, region.height):
        return region
    raise RuntimeError(f"unexpected render result size {size[0]}x{size[1]} for a "
                       f"{full[0]}x{full[1]} frame (border {region})")


def _set_pass(render_pass, pixels: np.ndarray) -> None:
    """Fill a RenderPass from (H, W[, C]) float32 rows top to bottom (a pass stores them bottom
    to top). `foreach_set` copies the buffer in one go: about 2 ms for 1280x720 RGBA, where
    assigning `rect` a nested sequence takes a second."""
    render_pass.rect.foreach_set(np.ascontiguousarray(pixels[::-1], np.float32).reshape(-1))


def _write_result(engine, rgba: np.ndarray, depth: np.ndarray, origin: Region,
                  full: tuple[int, int], region: Region) -> None:
    """Fill the engine's render result from `rgba`, `depth` (rows top to bottom) that cover
    `origin` of the full frame."""
    result = engine.begin_result(0, 0, engine.resolution_x, engine.resolution_y)
    try:
        target = _frame_target((result.resolution_x, result.resolution_y), full, region)
        if target != origin:  # a full-frame image for a border render: keep the border part
            rows = slice(target.y - origin.y, target.y - origin.y + target.height)
            cols = slice(target.x - origin.x, target.x - origin.x + target.width)
            rgba, depth = rgba[rows, cols], depth[rows, cols]
        layer = result.layers[0]
        _set_pass(layer.passes["Combined"], rgba)
        depth_pass = layer.passes.get("Depth")
        if depth_pass is not None:
            _set_pass(depth_pass, depth)
    finally:
        engine.end_result(result)


def _print_stats(stats: dict) -> None:
    if bpy.app.background:
        parts = ", ".join(f"{k[:-3]} {v:.0f}" for k, v in stats.items() if k.endswith("_ms"))
        print(f"Gaussian splats: {int(stats.get('gaussians', 0)):,} splats, "
              f"{int(stats.get('width', 0))}x{int(stats.get('height', 0))}: {parts} ms", flush=True)


# ------------------------------------------------------------------------------- the engine

class SplatRenderEngine(bpy.types.RenderEngine):
    """Composes splats for the compositor bridge (in the helper scene) or, as a scene's own
    engine, renders the splats alone."""

    bl_idname = ENGINE_ID
    bl_label = "Gaussian Splats"
    bl_use_preview = False
    bl_use_postprocess = True

    def update_render_passes(self, scene=None, renderlayer=None):
        self.register_pass(scene, renderlayer, "Combined", 4, "RGBA", "COLOR")
        if renderlayer is not None and renderlayer.use_pass_z:
            self.register_pass(scene, renderlayer, "Depth", 1, "Z", "VALUE")

    def render(self, depsgraph):
        try:
            if bridge.is_helper(depsgraph.scene):
                self._compose_for_bridge()
            else:
                self._render_splats_only(depsgraph)
        except Exception as error:  # report, never crash the render job
            traceback.print_exc()
            message = f"the splats could not be composed: {error}"
            self.report({"ERROR"}, f"Gaussian splats: {message}")
            self.error_set(f"Gaussian splats: {message}")
            fail_render(bpy.data.scenes.get(_state.scene or "") or depsgraph.scene,
                        str(error) if str(error) in _state.errors else message, "compose")

    def _compose_for_bridge(self) -> None:
        start = time.perf_counter()
        main = bpy.data.scenes.get(_state.scene) if _state.scene else None
        if main is None:
            raise RuntimeError("the splat composite was rendered outside a render of a scene")
        layer_name = bridge.bridge_view_layer(main) or main.view_layers[0].name
        mesh_rgba, mesh_depth, timings = read_render_layer(main, layer_name)
        layer_name = timings.pop("layer")
        shadow = timings.pop("shadow")
        full = frame_size(main.render)
        region = render_region(*full, render_border(main.render))
        height, width = mesh_depth.shape
        origin = _frame_target((width, height), full, region)
        frame = _state.frames.get((main.name, layer_name))
        settings = settings_of(main)
        stats = {"width": width, "height": height, "gaussians": 0, **timings}
        for warning in (frame.warnings if frame is not None else ()):
            print(f"Gaussian splats: {warning}")
        if frame is not None and frame.frame != main.frame_current:
            print(f"Gaussian splats: the splats were gathered at frame {frame.frame}, the render "
                  f"is of frame {main.frame_current}")
        if _state.errors:  # the render already failed (and was cancelled if it could be)
            raise RuntimeError(_state.errors[-1])
        if frame is None and settings.enabled and main.render.engine != ENGINE_ID:
            raise RuntimeError(f"no splats were gathered for scene {main.name!r}, view layer "
                               f"{layer_name!r} (the render's frame_change_post handler did "
                               f"not run for it)")
        if (main.render.engine == ENGINE_ID or not settings.enabled or frame is None
                or frame.camera is None or len(frame.gaussians) == 0):
            rgba, depth = mesh_rgba, mesh_depth
        else:
            if origin != Region(0, 0, *full):  # a cropped border: compose the whole frame
                mesh_rgba, mesh_depth = embed(mesh_rgba, mesh_depth, origin, *full)
            composed = compose(frame.gaussians, frame.camera, mesh_rgba, mesh_depth,
                               **frame.render_options())
            rgba, depth = composed.rgba[origin.slices()], composed.depth[origin.slices()]
            stats.update(gaussians=len(frame.gaussians), gather_ms=frame.gather_ms,
                         native_ms=composed.stats.get("ms_total", 0.0),
                         colour_ms=composed.stats.get("colour_ms", 0.0))
            if _wants_splat_passes(main):
                _state.pending_passes[main.name] = (
                    main.frame_current, _splat_passes(frame, main, full, region))
        if shadow is not None and shadow.shape[:2] == rgba.shape[:2]:
            # Proxies (shadow catchers) are left out of the mesh layer; their shadows darken
            # the composite, splats included (README, "Splats to meshes").
            rgba = apply_shadow_catcher(rgba, shadow)
        before_write = time.perf_counter()
        _write_result(self, rgba, depth, origin, full, region)
        stats["result_ms"] = 1000 * (time.perf_counter() - before_write)
        stats["total_ms"] = 1000 * (time.perf_counter() - start)
        last_stats.clear()
        last_stats.update(stats)
        _print_stats(stats)

    def _render_splats_only(self, depsgraph) -> None:
        start = time.perf_counter()
        scene = depsgraph.scene
        frame = capture_frame(scene, depsgraph)
        full = frame_size(scene.render)
        region = render_region(*full, render_border(scene.render))
        probe = self.begin_result(0, 0, self.resolution_x, self.resolution_y)
        size = (probe.resolution_x, probe.resolution_y)
        self.end_result(probe, cancel=True)
        target = _frame_target(size, full, region)
        background = None if scene.render.film_transparent else world_colour(scene)
        if frame.camera is None or len(frame.gaussians) == 0:
            rgba = np.zeros((target.height, target.width, 4), np.float32)
            if background is not None:
                rgba[..., :3], rgba[..., 3] = background, 1.0
            depth = np.full((target.height, target.width), FAR, np.float32)
        else:
            layer = splat_layer(frame.gaussians, frame.camera, background=background,
                                **frame.render_options())
            rgba, depth = layer.rgba[target.slices()], layer.depth[target.slices()]
        _write_result(self, rgba, depth, target, full, region)
        last_stats.clear()
        last_stats.update(width=target.width, height=target.height,
                          gaussians=len(frame.gaussians), gather_ms=frame.gather_ms,
                          total_ms=1000 * (time.perf_counter() - start))


def _wants_splat_passes(scene) -> bool:
    settings = scene.render.image_settings
    multilayer = (getattr(settings, "media_type", None) == "MULTI_LAYER_IMAGE"
                  or settings.file_format == "OPEN_EXR_MULTILAYER")
    return multilayer and settings_of(scene).splat_passes


def _splat_passes(frame: FrameSplats, scene, full: tuple[int, int], region: Region):
    """The splat layer alone, over the area of the file Blender writes."""
    layer = splat_layer(frame.gaussians, frame.camera, **frame.render_options())
    if scene.render.use_border and scene.render.use_crop_to_border:
        layer.rgba, layer.depth = layer.rgba[region.slices()], layer.depth[region.slices()]
    elif scene.render.use_border:  # Blender leaves the outside of a border empty
        inside = np.zeros(layer.depth.shape, bool)
        inside[region.slices()] = True
        layer.rgba[~inside] = 0.0
        layer.depth[~inside] = FAR
    return layer


def written_file(scene) -> str | None:
    """The image file Blender has just written for the current frame (a still or an animation
    frame: both names are tried, the one written since the frame began wins)."""
    render = scene.render
    frame = scene.frame_current
    animation = render.frame_path(frame=frame)
    candidates = [animation]
    digits = f"{frame:04d}"
    extension = render.file_extension if render.use_file_extension else ""
    stem = animation[:-len(extension)] if extension and animation.endswith(extension) else animation
    if "#" not in render.filepath and stem.endswith(digits):
        candidates.append(stem[:-len(digits)] + extension)
    elif "#" in render.filepath and "{" not in render.filepath:
        still = bpy.path.abspath(render.filepath)
        if extension and not still.lower().endswith(extension.lower()):
            still += extension
        candidates.append(still)
    fresh = [(os.stat(p).st_mtime_ns, p) for p in candidates if os.path.exists(p)
             and os.stat(p).st_mtime_ns >= _state.frame_start_ns - 50_000_000]
    return max(fresh)[1] if fresh else None


# ------------------------------------------------------------------------------- handlers

# ------------------------------------------------------------------------ failing loudly
#
# A render that cannot compose the splats must fail, never write an image that silently lacks
# them. Python cannot cancel a render directly; Blender cancels one itself when the scene it
# renders has no camera ("Cannot render, no camera": the render stops, nothing is written,
# `bpy.ops.render.render` reports the error and returns CANCELLED, `blender -b -a` exits 1).
# So a failure found when the render starts (render_init: a missing module, a bridge that is
# not set up) clears the scene's camera for this render; `render_complete`/`render_cancel` put
# it back. (Later, from frame_change_post, the camera has already been evaluated: a failure to
# gather the splats is recorded there and fails the compose step.) That is done in background
# renders only, which run on the main thread: an interactive render runs its handlers in the
# render job's thread, where changing data is unsafe, so there the error is reported in the
# window when the render ends and written files of failed frames are deleted.
# A failure while composing (the helper engine, after the meshes rendered) is too late for the
# camera: in background Blender it raises Blender's own break signal (SIGINT, what Ctrl+C does:
# the render is cancelled and nothing is written; Blender ends the process on a second one,
# exit code 2); where Blender has no such handler (the `bpy` module) the frame's written files
# are deleted and `last_errors()` says why.

def _blender_handles_sigint() -> bool:
    """Blender's command-line break handler is installed (not Python's or the default one)."""
    import signal
    return bpy.app.background and signal.getsignal(signal.SIGINT) is None


def fail_render(scene, message: str, stage: str) -> None:
    """Make the current render of `scene` fail with `message` (see above). `stage`: "init"
    (render_init, before the meshes render: the camera can still stop it), "frame" (while
    Blender prepares the frame: recorded, the compose step fails with it) or "compose"."""
    if message not in _state.errors:
        print(f"Gaussian splats: ERROR: {message}", flush=True)
        _state.errors.append(message)
    if scene is None:
        return
    _state.failed_frames.add(scene.frame_current)
    if not bpy.app.background or stage == "frame":
        return
    if stage == "init":
        if scene.name not in _state.camera_restore and scene.camera is not None:
            _state.camera_restore[scene.name] = scene.camera
            scene.camera = None
    elif _blender_handles_sigint():
        import signal
        os.kill(os.getpid(), signal.SIGINT)


def _render_blockers(scene) -> list[str]:
    """Why the splats of `scene` cannot be composed into its final render (empty: they can)."""
    try:
        dependencies.require("splatcore", "Rendering Gaussian splats")
        if _wants_splat_passes(scene):
            dependencies.require("OpenImageIO", "Splat Passes in multilayer EXR files "
                                                "(Properties > Render > Gaussian Splats; "
                                                "turn it off to render without them)")
    except dependencies.MissingModule as error:
        return [str(error)]
    found = bridge.problems(scene)
    if found:
        return [f"{'; '.join(found)}: set it up in Properties > Render > Gaussian Splats "
                f"(Set Up / Repair, or bpy.ops.splat.compositor_bridge()) before rendering"]
    return []


def last_errors() -> list[str]:
    """Why the current or last render failed (empty when it did not)."""
    return list(_state.errors)


# ------------------------------------------------------------------------------- handlers
# The bridge is set up before any render: when a file loads, and when a scene gains splats.
# Render handlers leave the compositor alone (from Blender 5.1; see `_SET_UP_AT_RENDER`):
# Blender 5.2 crashes (SIGSEGV in the compositor's worker threads, or an abort) when a Render
# Layers node for another scene is added to the compositor from render_init. What they still
# change is small and was tried on 5.2: `use_render_cache` (read after render_init) and, for a
# failure, the scene's camera.

@persistent
def _on_render_init(scene, _depsgraph=None) -> None:
    if bridge.is_helper(scene):
        return
    _state.scene = scene.name
    _state.frames.clear()
    _state.pending_passes.clear()
    _state.errors.clear()
    _state.failed_frames.clear()
    _state.frame_start_ns = time.time_ns()
    settings = settings_of(scene)
    if not settings.enabled or scene.render.engine == ENGINE_ID:
        return
    try:
        if bridge.bridge_node(scene) is None and not bridge.has_splats(scene):
            return
        if _SET_UP_AT_RENDER and bridge.ensure_bridge(scene):
            print(f"Gaussian splats: compositor bridge set up for scene {scene.name!r}")
        blockers = _render_blockers(scene)
        if blockers:
            fail_render(scene, "; ".join(blockers), "init")
            return
        if render_result_image() is None or _state.force_cache_file:
            # `blender -b -a`: no Render Result image to read the render from; the render
            # cache writes it (this flag is read when the render starts, after this handler).
            _state.cache_restore[scene.name] = scene.render.use_render_cache
            scene.render.use_render_cache = True
    except Exception as error:
        traceback.print_exc()
        fail_render(scene, f"cannot prepare the splat composite: {error}", "init")


@persistent
def _on_render_pre(scene, _depsgraph=None) -> None:
    if not bridge.is_helper(scene):
        _state.frame_start_ns = time.time_ns()


@persistent
def _on_frame_change(scene, depsgraph=None) -> None:
    if (depsgraph is None or _state.scene is None or scene.name != _state.scene
            or depsgraph.mode != "RENDER" or bridge.is_helper(scene)
            or not settings_of(scene).enabled or scene.render.engine == ENGINE_ID
            or _state.errors):
        return
    try:
        frame = capture_frame(scene, depsgraph)
    except Exception as error:
        traceback.print_exc()
        fail_render(scene, f"the splats could not be gathered: {error}", "frame")
        return
    _state.frames[(scene.name, depsgraph.view_layer.name)] = frame


def _remove_failed_file(scene) -> None:
    """A frame whose splats failed: the file Blender just wrote lacks them, so it goes."""
    path = written_file(scene)
    if path is not None:
        with contextlib.suppress(OSError):
            os.remove(path)
        print(f"Gaussian splats: removed {path}: its splats could not be composed", flush=True)


@persistent
def _on_render_write(scene, _depsgraph=None) -> None:
    if bridge.is_helper(scene):
        return
    if scene.frame_current in _state.failed_frames:
        _remove_failed_file(scene)
        return
    pending = _state.pending_passes.pop(scene.name, None)
    if pending is None:
        return
    frame, layer = pending
    if frame != scene.frame_current:
        return
    try:
        path = written_file(scene)
        if path is None:
            raise RuntimeError("cannot find the written multilayer EXR to add the splat "
                               "passes to")
        exr_layers.append_layers(path, {"Splats.Combined": ("RGBA", layer.rgba),
                                        "Splats.Depth": ("Z", layer.depth[..., None])})
    except Exception as error:
        traceback.print_exc()
        fail_render(scene, f"the splat passes could not be added to the file: {error}",
                    "compose")
        _remove_failed_file(scene)


@persistent
def _on_render_done(scene, _depsgraph=None) -> None:
    if bridge.is_helper(scene):
        return
    if scene.name in _state.cache_restore:
        scene.render.use_render_cache = _state.cache_restore.pop(scene.name)
    camera = _state.camera_restore.pop(scene.name, None)
    if camera is not None:
        scene.camera = camera
    _state.scene = None
    _state.frames.clear()
    _state.pending_passes.clear()
    if _state.errors and not bpy.app.background:
        message = _state.errors[-1]
        bpy.app.timers.register(lambda: _report_in_window(message), first_interval=0.0)


def _report_in_window(message: str) -> None:
    """An interactive render failed: say so in the status bar and the Info editor."""
    try:
        bpy.ops.splat.report_render_error(message=message)
    except RuntimeError:
        pass  # the report is what the operator is for; bpy raises for ERROR reports
    return None


class SPLAT_OT_report_render_error(bpy.types.Operator):
    """Report why the last render could not compose its splats"""

    bl_idname = "splat.report_render_error"
    bl_label = "Splat Render Error"
    bl_options = {"INTERNAL"}

    message: bpy.props.StringProperty()

    def execute(self, context):
        self.report({"ERROR"}, self.message)
        return {"FINISHED"}


_object_counts: dict[str, int] = {}
_helper_made_for: set[str] = set()   # scenes whose helper scene was made in the last update

# Blender up to 5.0 takes the bridge being set up from render_init (a script that adds splats
# and renders at once relies on it); 5.2 crashes (see the handlers' note), so from 5.1 on a
# render finds the bridge ready or fails with what to do.
_SET_UP_AT_RENDER = bpy.app.version < (5, 1, 0)


@persistent
def _on_depsgraph_update(scene, depsgraph) -> None:
    """Set the bridge up as soon as a scene gains splats, before anything renders it: in the
    UI on the main thread through a timer (not inside the depsgraph update), in background
    from the update itself (no event loop runs timers before a script renders). Blender 5.2
    crashes when one update both makes a scene and points a Render Layers node at it, so a
    new helper scene is made in one update and the bridge in the next."""
    if bridge.is_helper(scene) or getattr(depsgraph, "mode", "VIEWPORT") != "VIEWPORT":
        return
    waiting = scene.name in _helper_made_for
    if not waiting and not depsgraph.id_type_updated("OBJECT"):
        return
    count = len(scene.objects)
    if not waiting and _object_counts.get(scene.name) == count:
        return
    _object_counts[scene.name] = count
    if not settings_of(scene).enabled or bridge.bridge_node(scene) is not None \
            or scene.render.engine == ENGINE_ID or not bridge.has_splats(scene):
        return
    if not bpy.app.background:
        name = scene.name
        bpy.app.timers.register(lambda: _set_up_later(name), first_interval=0.0)
    elif _SET_UP_AT_RENDER:
        return  # the render sets it up (a script's scene changes nothing before)
    elif bridge.helper_scene(create=False) is None:
        bridge.helper_scene()
        _helper_made_for.add(scene.name)
    else:
        _helper_made_for.discard(scene.name)
        _set_up_later(scene.name)


def _set_up_later(scene_name: str) -> None:
    scene = bpy.data.scenes.get(scene_name)
    if _state.scene is not None or (hasattr(bpy.app, "is_job_running")
                                    and bpy.app.is_job_running("RENDER")):
        return 0.5  # never while a render runs: try again when it is done
    if scene is not None and scene.render.engine != ENGINE_ID and bridge.has_splats(scene) \
            and bridge.bridge_node(scene) is None and settings_of(scene).enabled:
        try:
            bridge.ensure_bridge(scene)
        except Exception:
            traceback.print_exc()
    return None


@persistent
def _on_load_post(*_args) -> None:
    """A file opened (also `blender -b file.blend -a`, before it renders): bridge its scenes."""
    _object_counts.clear()
    _helper_made_for.clear()
    for scene in list(bpy.data.scenes):
        if not bridge.is_helper(scene):
            _set_up_later(scene.name)


_HANDLERS = (
    ("depsgraph_update_post", _on_depsgraph_update),
    ("load_post", _on_load_post),
    ("render_init", _on_render_init),
    ("render_pre", _on_render_pre),
    ("frame_change_post", _on_frame_change),
    ("render_write", _on_render_write),
    ("render_complete", _on_render_done),
    ("render_cancel", _on_render_done),
)

# Blender's own panels that also make sense for the splats-only engine.
_SHARED_PANELS = ("RENDER_PT_color_management", "RENDER_PT_color_management_curves",
                  "RENDER_PT_color_management_display_settings",
                  "RENDER_PT_color_management_white_balance", "RENDER_PT_format")


def register() -> None:
    for cls in (SplatRenderEngine, SPLAT_OT_report_render_error):
        if not getattr(cls, "is_registered", False):
            bpy.utils.register_class(cls)
    for name, handler in _HANDLERS:
        handlers = getattr(bpy.app.handlers, name)
        if handler not in handlers:
            handlers.append(handler)
    for name in _SHARED_PANELS:
        panel = getattr(bpy.types, name, None)
        engines = getattr(panel, "COMPAT_ENGINES", None)
        if isinstance(engines, set):
            engines.add(ENGINE_ID)


def unregister() -> None:
    for name, handler in _HANDLERS:
        handlers = getattr(bpy.app.handlers, name)
        if handler in handlers:
            handlers.remove(handler)
    for name in _SHARED_PANELS:
        panel = getattr(bpy.types, name, None)
        engines = getattr(panel, "COMPAT_ENGINES", None)
        if isinstance(engines, set):
            engines.discard(ENGINE_ID)
    for cls in (SPLAT_OT_report_render_error, SplatRenderEngine):
        if getattr(cls, "is_registered", False):
            bpy.utils.unregister_class(cls)
