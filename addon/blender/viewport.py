"""Splats in the 3D viewport: a draw handler over Solid and Material Preview shading.

For each 3D view, the native renderer draws the splats as the view's camera sees them (colour
and expected depth), in a background thread; the draw handler (POST_VIEW) draws that image over
the viewport with a depth test against the viewport's own depth buffer, so meshes in front hide
the splats and splats in front hide meshes (per pixel, at the splats' expected depth: the exact
soft composite is what final renders do).

Progressive: when the view (or the scene) changes, a coarse image (about
`Scene.splat_render.viewport_coarse_pixels` pixels) is requested first; once the view has
rested for `REST_SECONDS`, the full-resolution one (`viewport_resolution`). Coarse and full
images render in two threads of their own, so a coarse image never waits behind a full one of
an earlier view. Rendering never runs in the draw callback, so a large scene never blocks the
UI for a render (gathering the splats of an edited object does run on the main thread, as
reading Blender data must: about 0.2 s per million splats).

Never a stale view: an image of another view (view or projection matrix, region size) is drawn
only while the view moves (changed less than `REST_SECONDS` ago: an orbit, a smooth-view
turn); once it rests, only an image of this view is drawn (coarse, then full), and nothing
until one is ready. Before this, the previous view's picture stayed up for seconds after
numpad 1/3/7, numpad 5 or an orbit, composed with the new view's grid and gizmo. An image of
this view with older splats (training's updates, an edit) is drawn until the new one is ready;
a training update asks for its image at once (`refresh`), so the view redraws only when it is.

Switches: `Scene.splat_render.viewport` (all splats of the scene) and
`Object.splat.show_in_viewport` (one object). Perspective and orthographic views are drawn
(front, right, top...: an orthographic view renders exactly, docs/conventions.md "Cameras beyond
the pinhole", clipped to the view's own clip range, which reaches behind its origin); looking
through a panoramic camera, the view is a perspective one and is drawn as such. The viewport
shows the reference look (display sRGB, as "Standard" shows it), whatever the scene's view
transform.

The pieces are usable without a 3D view (tests draw into a `gpu.types.GPUOffScreen`):
`camera_from_view`, `render_view` (no GPU) and `draw_image` (GPU).
"""

from __future__ import annotations

import atexit
import threading
import time
from dataclasses import dataclass

import bpy
import numpy as np
from bpy.app.handlers import persistent

from ..core import colour
from ..core.cameras import CAMERA_AXIS_FLIP, Camera
from ..core.gaussians import Gaussians
from ..core.priority import at_background_priority
from ..core.render.renderer import RenderResult, render, viewport_image
from .sources import gather
from .threads import scene_threads
from .splat_object import BOUNDS_FLAG, drawn_by_addon, needs_sync, sync_display  # noqa: F401

REST_SECONDS = 0.15


# --------------------------------------------------------------------- cameras and images

def _is_orthographic(p: np.ndarray) -> bool:
    return abs(p[3, 3] - 1.0) <= 1e-9 and np.abs(p[3, :3]).max() <= 1e-9


def camera_from_view(view_matrix, window_matrix, width: int, height: int,
                     scale: float = 1.0) -> Camera | None:
    """The camera of a 3D view (OpenGL view and projection matrices, region size in pixels),
    for an image `scale` times the region's size: a pinhole, or ORTHO for an orthographic view
    (then with the view's far clip; `view_near` gives its near one); None for anything else.

    With P the projection, a perspective view's point (x, y, z), z < 0, lands at
    u = (P00 x/(-z) - P02 + 1) W/2 and v = (1 - P11 y/(-z) + P12) H/2, so in OpenCV terms
    fx = P00 W/2, cx = (1 - P02) W/2, fy = P11 H/2, cy = (1 + P12) H/2. An orthographic one's
    at u = (P00 x + P03 + 1) W/2 and v = (1 - P11 y - P13) H/2: fx = P00 W/2,
    cx = (1 + P03) W/2, fy = P11 H/2, cy = (1 - P13) H/2 (OpenCV's y is -y).
    """
    p = np.asarray(window_matrix, np.float64)
    ortho = _is_orthographic(p)
    if not ortho and (abs(p[3, 3]) > 1e-9 or abs(p[3, 2] + 1.0) > 1e-9):
        return None
    w = max(1, int(round(width * scale)))
    h = max(1, int(round(height * scale)))
    world_to_camera = CAMERA_AXIS_FLIP @ np.asarray(view_matrix, np.float64)
    if ortho:
        return Camera(world_to_camera, p[0, 0] * w / 2, p[1, 1] * h / 2, (1 + p[0, 3]) * w / 2,
                      (1 - p[1, 3]) * h / 2, w, h, model="ORTHO", far=(p[2, 3] - 1.0) / p[2, 2])
    return Camera(world_to_camera, p[0, 0] * w / 2, p[1, 1] * h / 2, (1 - p[0, 2]) * w / 2,
                  (1 + p[1, 2]) * h / 2, w, h)


def view_near(window_matrix, near: float) -> float:
    """The near plane a view renders with: the splat setting `near` for a perspective view,
    the view's own near clip for an orthographic one (Blender puts it behind the view's
    origin, at -clip_end/2: everything in the view's clip range is drawn). NDC z = -1 at
    camera depth z = (P23 + 1) / P22."""
    p = np.asarray(window_matrix, np.float64)
    return (p[2, 3] + 1.0) / p[2, 2] if _is_orthographic(p) else near


@dataclass
class ViewportImage:
    """A rendered view, ready to draw: rows bottom to top (OpenGL's texture order)."""

    key: tuple
    rgba: np.ndarray          # (h, w, 4) float32 premultiplied display sRGB
    depth: np.ndarray         # (h, w) float32 depth-buffer values (1: nothing)
    coarse: bool
    seconds: float


# Each thread's last render images, rendered into again at the same size: fresh images cost
# their page faults every frame (a third of a 3840x2160 frame's time).
_renders = threading.local()


def _render_images(camera: Camera) -> RenderResult:
    images = getattr(_renders, "images", None)
    if images is None or images.alpha.shape != (camera.height, camera.width):
        images = _renders.images = RenderResult(
            np.empty((camera.height, camera.width, 3), np.float32),
            np.empty((camera.height, camera.width), np.float32),
            np.empty((camera.height, camera.width), np.float32))
    return images


def render_view(gaussians: Gaussians, camera: Camera, window_matrix, *, key: tuple = (),
                coarse: bool = False, color_space: str = "SRGB", antialiased: bool = False,
                near: float = 0.01, sh_degree: int | None = None, threads: int = 0) -> ViewportImage:
    """Render the splats for a view (no GPU, no bpy: runs in a worker thread)."""
    start = time.perf_counter()
    result = render(gaussians, camera, antialiased=antialiased,
                    near=view_near(window_matrix, near), sh_degree=sh_degree, threads=threads,
                    out=_render_images(camera))
    rgba, depth = viewport_image(result, window_matrix, threads=threads)
    if color_space == "LINEAR":
        colour.display_from_linear(rgba, out=rgba, threads=threads)
    return ViewportImage(key, rgba, depth, coarse, time.perf_counter() - start)


# ---------------------------------------------------------------------------- GPU drawing

_shader_cache: dict[str, object] = {}
atexit.register(_shader_cache.clear)  # GPU objects go before Blender checks for leaks

_VERTEX = """
void main()
{
  uv = pos * 0.5 + 0.5;
  gl_Position = vec4(pos, 0.0, 1.0);
}
"""

_FRAGMENT = """
float srgb_to_linear(float c)
{
  return c <= 0.04045 ? c / 12.92 : pow((c + 0.055) / 1.055, 2.4);
}

void main()
{
  vec4 c = texture(colour_tex, uv);
  if (c.a < 1.0 / 255.0) {
    discard;
  }
  gl_FragDepth = texture(depth_tex, uv).r;
  if (srgbTarget) {
    /* An sRGB framebuffer encodes on write: hand it linear (display-referred) colour. */
    vec3 straight = max(c.rgb / c.a, vec3(0.0));
    c.rgb = vec3(srgb_to_linear(straight.r), srgb_to_linear(straight.g),
                 srgb_to_linear(straight.b)) * c.a;
  }
  frag = c;
}
"""


def _shader():
    shader = _shader_cache.get("image")
    if shader is None:
        import gpu

        interface = gpu.types.GPUStageInterfaceInfo("splat_viewport_interface")
        interface.smooth("VEC2", "uv")
        info = gpu.types.GPUShaderCreateInfo()
        info.push_constant("BOOL", "srgbTarget")   # set by Blender for sRGB framebuffers
        info.sampler(0, "FLOAT_2D", "colour_tex")
        info.sampler(1, "FLOAT_2D", "depth_tex")
        info.vertex_in(0, "VEC2", "pos")
        info.vertex_out(interface)
        info.fragment_out(0, "VEC4", "frag")
        if hasattr(info, "depth_write"):  # Blender 4.4+; 4.2/4.3 write gl_FragDepth as is
            info.depth_write("ANY")
        info.vertex_source(_VERTEX)
        info.fragment_source(_FRAGMENT)
        shader = gpu.shader.create_from_info(info)
        _shader_cache["image"] = shader
    return shader


# GPU textures of the image last drawn in each view. GPU objects are made and freed only here,
# in the drawing (main) thread: the worker thread never holds one.
_texture_cache: dict[object, tuple[ViewportImage, tuple]] = {}
atexit.register(_texture_cache.clear)


def _textures(image: ViewportImage, cache_key=None):
    cached = _texture_cache.get(cache_key) if cache_key is not None else None
    if cached is not None and cached[0] is image:
        return cached[1]
    import gpu

    h, w = image.depth.shape
    # Colour as 8 bits, what a display shows: software OpenGL took 0.1-0.2 s more per new
    # image to take a float one (issue 36). Depth stays float, for the depth test.
    textures = (
        gpu.types.GPUTexture((w, h), format="RGBA8", data=gpu.types.Buffer(
            "FLOAT", w * h * 4, image.rgba.reshape(-1))),
        gpu.types.GPUTexture((w, h), format="R32F", data=gpu.types.Buffer(
            "FLOAT", w * h, image.depth.reshape(-1))))
    if cache_key is not None:
        _texture_cache[cache_key] = (image, textures)
    return textures


def draw_image(image: ViewportImage, cache_key=None) -> None:
    """Draw `image` over the bound framebuffer, covering it, with a depth test against its
    depth buffer (which is left unchanged). With a `cache_key` (a view), the textures are kept
    for the next draw of the same image."""
    import gpu
    from gpu_extras.batch import batch_for_shader

    shader = _shader()
    colour_tex, depth_tex = _textures(image, cache_key)
    quad = _shader_cache.get("quad")
    if quad is None:
        quad = batch_for_shader(shader, "TRI_STRIP",
                                {"pos": [(-1, -1), (1, -1), (-1, 1), (1, 1)]})
        _shader_cache["quad"] = quad
    gpu.state.depth_test_set("LESS_EQUAL")
    gpu.state.depth_mask_set(False)
    gpu.state.blend_set("ALPHA_PREMULT")
    try:
        shader.bind()
        shader.uniform_sampler("colour_tex", colour_tex)
        shader.uniform_sampler("depth_tex", depth_tex)
        quad.draw(shader)
    finally:
        gpu.state.blend_set("NONE")
        gpu.state.depth_test_set("NONE")


# ------------------------------------------------------------------------ background renders

@dataclass
class _Job:
    region: int
    key: tuple
    gaussians: Gaussians
    camera: Camera
    window_matrix: np.ndarray
    coarse: bool
    options: dict


def view_of(key: tuple) -> tuple:
    """The view part of a draw key (see `draw_view`): view and projection matrices, region
    size; not the splats or the render options."""
    return key[:4]


class ViewportRenderer:
    """Two worker threads, one for coarse and one for full-resolution jobs, rendering the latest
    job of each kind for each view; results are picked up by the draw handler. A newer job
    replaces an older waiting one of its kind."""

    def __init__(self) -> None:
        self._lock = threading.Condition()
        self._jobs: dict[tuple[int, bool], _Job] = {}   # (region, coarse) -> the job waiting
        self._wanted: dict[int, tuple] = {}              # region -> the view last submitted
        self._results: dict[int, ViewportImage] = {}
        self._fresh = False
        self._threads: dict[bool, threading.Thread] = {}
        self._stop = False
        self._running = 0
        self.errors: list[str] = []

    def submit(self, job: _Job) -> None:
        with self._lock:
            self._jobs[(job.region, job.coarse)] = job
            self._wanted[job.region] = view_of(job.key)
            thread = self._threads.get(job.coarse)
            if thread is None or not thread.is_alive():
                self._stop = False
                thread = threading.Thread(target=self._run, args=(job.coarse,), daemon=True,
                                          name=f"splat-viewport-{'coarse' if job.coarse else 'full'}")
                self._threads[job.coarse] = thread
                thread.start()
            self._lock.notify_all()

    def result(self, region: int) -> ViewportImage | None:
        with self._lock:
            return self._results.get(region)

    def take_fresh(self) -> bool:
        """True once after new results arrived (the caller redraws)."""
        with self._lock:
            fresh, self._fresh = self._fresh, False
            return fresh

    def busy(self) -> bool:
        with self._lock:
            return bool(self._jobs) or self._running > 0

    def forget(self, region: int) -> None:
        with self._lock:
            for coarse in (True, False):
                self._jobs.pop((region, coarse), None)
            self._wanted.pop(region, None)
            self._results.pop(region, None)

    def wait(self, timeout: float = 30.0) -> bool:
        """Wait until no job is waiting or running (tests)."""
        deadline = time.monotonic() + timeout
        with self._lock:
            while self._jobs or self._running:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                self._lock.wait(remaining)
        return True

    def stop(self) -> None:
        with self._lock:
            self._stop = True
            self._jobs.clear()
            self._wanted.clear()
            self._results.clear()
            self._lock.notify_all()

    def _keeps(self, region: int, image: ViewportImage) -> bool:
        """Whether a finished image replaces the region's result: one of the view last
        submitted beats one of another view; a coarse one never replaces a full one of the
        same key."""
        old, wanted = self._results.get(region), self._wanted.get(region)
        if old is None:
            return True
        if view_of(image.key) != wanted:
            return view_of(old.key) != wanted
        return view_of(old.key) != wanted or not (image.coarse and not old.coarse
                                                  and old.key == image.key)

    def _run(self, coarse: bool) -> None:
        while True:
            with self._lock:
                while not self._stop and not any(c == coarse for _, c in self._jobs):
                    self._lock.wait()
                if self._stop:
                    return
                region, _ = next(k for k in self._jobs if k[1] == coarse)
                job = self._jobs.pop((region, coarse))
                self._running += 1

            def draw() -> ViewportImage:
                return render_view(job.gaussians, job.camera, job.window_matrix, key=job.key,
                                   coarse=job.coarse, **job.options)
            try:
                # On the UI's cores (one kernel thread) the render yields to the UI's redraws.
                image = at_background_priority(draw) if job.options["threads"] == 1 else draw()
            except Exception as error:  # a bad frame must not kill the worker
                image = None
                self.errors.append(str(error))
            with self._lock:
                self._running -= 1
                if image is not None and self._keeps(region, image):
                    self._results[region] = image
                    self._fresh = True
                self._lock.notify_all()
            image = job = None  # hold no image (nor its GPU textures) while waiting


renderer = ViewportRenderer()


# --------------------------------------------------------------------------- draw handler

@dataclass
class _ViewState:
    key: tuple = ()
    changed_at: float = 0.0          # the key's last change (the view's or the splats')
    view_changed_at: float = 0.0     # the view's last change
    full_requested: bool = False
    job: _Job | None = None          # the full-resolution job to send once the view rests


_views: dict[int, _ViewState] = {}
_combined: dict[tuple, Gaussians] = {}


def viewport_splats(depsgraph, scene) -> tuple[Gaussians, dict] | None:
    """The splats a viewport shows (per-object switches applied) and the render options."""
    result = gather.gather(depsgraph)
    batches = [b for b in result.batches if b.shown]
    if not batches:
        return None
    if len(batches) == len(result.batches):
        gaussians = result.gaussians
    else:
        key = tuple(id(b.gaussians) for b in batches)
        gaussians = _combined.get(key)
        if gaussians is None:
            degree = max(b.gaussians.degree for b in batches)
            parts = [b.gaussians.with_degree(degree) if b.gaussians.degree != degree
                     else b.gaussians for b in batches]
            gaussians = Gaussians(*(np.concatenate([getattr(p, n) for p in parts]) for n in (
                "means", "log_scales", "quats", "opacity_logits", "sh")))
            _combined.clear()
            _combined[key] = gaussians
    settings = scene.splat_render
    antialiased = {"OBJECT": all(b.antialiased for b in batches), "ON": True,
                   "OFF": False}[settings.antialiased]
    spaces = {b.color_space for b in batches}
    options = dict(color_space="LINEAR" if spaces == {"LINEAR"} else "SRGB",
                   antialiased=antialiased, near=settings.near,
                   sh_degree=min(settings.sh_degree, gaussians.degree),
                   threads=scene_threads(scene, beside_ui=True))
    return gaussians, options


def _same_view(key: tuple, previous: tuple) -> bool:
    """Whether two draw keys (see `draw_view`) differ only in the splats or render options."""
    return bool(previous) and key[:4] == previous[:4] and key[-1] == previous[-1]


def _draw() -> None:
    draw_view(bpy.context)


def _shows_splats(scene, space) -> bool:
    """Whether the add-on draws splats in this 3D view (the scene's switch, the shading)."""
    settings = getattr(scene, "splat_render", None)
    return settings is not None and settings.viewport and \
        space.shading.type in ("SOLID", "MATERIAL")


def _update_view(scene, depsgraph, region, rv3d) -> tuple | None:
    """Ask for the images this view needs as the splats are now (a coarse one first after a
    view change, full resolution straight away when only the splats changed); the view's draw
    key (see `draw_view`), None when it shows no splats."""
    settings = scene.splat_render
    region_id = region.as_pointer()
    found = viewport_splats(depsgraph, scene)
    view, window = np.array(rv3d.view_matrix), np.array(rv3d.window_matrix)
    if found is None or camera_from_view(view, window, region.width, region.height) is None:
        renderer.forget(region_id)
        _views.pop(region_id, None)
        _texture_cache.pop(region_id, None)
        return None
    gaussians, options = found
    key = (view.tobytes(), window.tobytes(), region.width, region.height, id(gaussians),
           tuple(sorted(options.items())), settings.viewport_resolution)
    state = _views.setdefault(region_id, _ViewState())
    if key == state.key:
        return key
    pixels = region.width * region.height
    coarse_scale = min(1.0, float(np.sqrt(settings.viewport_coarse_pixels / max(pixels, 1))))
    full_scale = settings.viewport_resolution
    if _same_view(key, state.key):
        # Only the splats changed (training's updates, an edit): the last image stays up until
        # the full one is ready; a coarse one between would flicker and cost a redraw.
        coarse_scale = full_scale
    if view_of(key) != view_of(state.key):
        state.view_changed_at = time.monotonic()
    state.key, state.changed_at, state.full_requested = key, time.monotonic(), False
    state.job = _Job(region_id, key, gaussians,
                     camera_from_view(view, window, region.width, region.height, full_scale),
                     window, False, options)
    if coarse_scale < full_scale:
        renderer.submit(_Job(region_id, key, gaussians, camera_from_view(
            view, window, region.width, region.height, coarse_scale), window, True, options))
    else:
        renderer.submit(state.job)
        state.full_requested = True
    _ensure_timer()
    return key


def draw_view(context) -> None:
    """The draw handler's work for one 3D view (`context`: scene, space_data, region,
    region_data and evaluated_depsgraph_get, as a draw callback's context has them)."""
    scene, space, region, rv3d = context.scene, context.space_data, context.region, \
        context.region_data
    if scene is None or rv3d is None or space is None or space.type != "VIEW_3D" or \
            not _shows_splats(scene, space):
        return
    _shader()  # made at the first redraw, not the first with splats (software OpenGL: 50 ms)
    key = _update_view(scene, context.evaluated_depsgraph_get(), region, rv3d)
    if key is None:
        return
    region_id = region.as_pointer()
    image = renderer.result(region_id)
    if image is not None and (view_of(image.key) == view_of(key) or
                              time.monotonic() - _views[region_id].view_changed_at < REST_SECONDS):
        draw_image(image, cache_key=region_id)


def _views_on_screen():
    """(scene, depsgraph, region, view) of each 3D view's main region the add-on draws
    splats in."""
    for window in bpy.context.window_manager.windows:
        for area in window.screen.areas:
            if area.type != "VIEW_3D" or not _shows_splats(window.scene, area.spaces.active):
                continue
            for region in area.regions:
                if region.type == "WINDOW" and region.as_pointer() in _views and \
                        region.data is not None:
                    yield window.scene, window.view_layer.depsgraph, region, region.data


def refresh() -> None:
    """Render each 3D view's splats again as they are now, without a redraw first (a job's new
    snapshot, shown in place of its object's data): the view redraws once, when the new image
    is ready (`_tick`). A redraw to see the new splats, then one for their image, cost two
    whole redraws per update (0.15 s each in software OpenGL, issue 36)."""
    for scene, depsgraph, region, rv3d in list(_views_on_screen()):
        _update_view(scene, depsgraph, region, rv3d)


def _redraw_views() -> None:
    """The 3D views' main regions (the image is drawn there only)."""
    for window in bpy.context.window_manager.windows:
        for area in window.screen.areas:
            if area.type == "VIEW_3D":
                for region in area.regions:
                    if region.type == "WINDOW":
                        region.tag_redraw()


def _tick():
    """Timer: ask for full resolution once a view rests (and redraw then: an image of the view
    before is not drawn after that); redraw when images arrive."""
    now = time.monotonic()
    rested = False
    for state in _views.values():
        if not state.full_requested and state.job is not None and \
                now - state.changed_at >= REST_SECONDS:
            renderer.submit(state.job)
            state.full_requested = rested = True
    if renderer.take_fresh() or rested:
        _redraw_views()
    waiting = renderer.busy() or any(not s.full_requested for s in _views.values())
    return 0.05 if waiting else None


def _ensure_timer() -> None:
    if not bpy.app.timers.is_registered(_tick):
        bpy.app.timers.register(_tick, first_interval=0.05)


# ------------------------------------------------------------------ the object's own drawing
# (`splat_object`: a splat object the add-on draws shows as its bounds, not one dot per splat;
# here: keeping that right whatever brings objects back)


def sync_scene(scene) -> int:
    """`sync_display` for every object of `scene`; how many changed."""
    return sum(sync_display(obj, scene) for obj in scene.objects)


def sync_all() -> int:
    """`sync_display` for every scene of the file; how many objects changed."""
    return sum(sync_scene(scene) for scene in bpy.data.scenes)


def on_switch_changed(_settings, context) -> None:
    """Update callback of `Object.splat.show_in_viewport` and `Scene.splat_render.viewport`."""
    if context.scene is not None:
        sync_scene(context.scene)


# When the display is set. A splat object gets it where it is made (`create_splat_object`, inside
# the operator, so the operator's undo step holds it); everything that brings objects back from
# stored state without running that code re-syncs here:
# - undo and redo (memfile steps of files made before, or of objects whose flag changed),
#   and opening a file: `undo_post`, `redo_post`, `load_post`, at once (outside any evaluation);
# - duplicate, append, link, paste, scripts: the objects the depsgraph reports as updated are
#   checked (no data written unless one is wrong); in the UI the fix runs from a timer, since
#   data must not be written during the depsgraph update; in background at once.


def _wrong_objects(scene, depsgraph) -> bool:
    if not depsgraph.id_type_updated("OBJECT"):
        return False
    for update in depsgraph.updates:
        original = getattr(update.id, "original", None)
        if isinstance(original, bpy.types.Object) and needs_sync(original, scene):
            return True
    return False


_sync_pending: set[str] = set()


@persistent
def _on_depsgraph_update(scene, depsgraph) -> None:
    """Objects new or changed in a scene: splat objects get the bounds display."""
    if scene.name in _sync_pending or not _wrong_objects(scene, depsgraph):
        return
    if bpy.app.background:
        sync_scene(scene)
    else:
        name = scene.name
        _sync_pending.add(name)
        bpy.app.timers.register(lambda: _sync_later(name), first_interval=0.0)


def _sync_later(scene_name: str) -> None:
    _sync_pending.discard(scene_name)
    scene = bpy.data.scenes.get(scene_name)
    if scene is not None:
        sync_scene(scene)
    return None


@persistent
def _on_stored_state(*_args) -> None:
    """After undo, redo and file load: the objects are as stored; put their display right."""
    _sync_pending.clear()
    sync_all()


_on_load_post = _on_stored_state  # (the name the tests and older callers use)

_HANDLERS = (("depsgraph_update_post", _on_depsgraph_update), ("load_post", _on_stored_state),
             ("undo_post", _on_stored_state), ("redo_post", _on_stored_state))
_handle = None


def register() -> None:
    global _handle
    if _handle is None:
        _handle = bpy.types.SpaceView3D.draw_handler_add(_draw, (), "WINDOW", "POST_VIEW")
    for name, handler in _HANDLERS:
        if handler not in getattr(bpy.app.handlers, name):
            getattr(bpy.app.handlers, name).append(handler)


def unregister() -> None:
    for name, handler in _HANDLERS:
        if handler in getattr(bpy.app.handlers, name):
            getattr(bpy.app.handlers, name).remove(handler)
    global _handle
    if _handle is not None:
        bpy.types.SpaceView3D.draw_handler_remove(_handle, "WINDOW")
        _handle = None
    if bpy.app.timers.is_registered(_tick):
        bpy.app.timers.unregister(_tick)
    renderer.stop()
    _views.clear()
    _combined.clear()
    _texture_cache.clear()
    _shader_cache.clear()
