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
   them exactly (`addon.core.render.composite.compose`) and returns the composite. The Gaussians' half
   of that (projection, depth sort, binning: `composite.prepare`) needs no mesh, so it runs on a
   thread of its own while Blender writes the render out to be read. The compositor hands
   it on to the Render Result (the Image Editor shows it), to the file or movie Blender writes,
   and to any compositor nodes downstream.
4. `render_write`: for multilayer EXR output, the splat layer's own colour, alpha and depth are
   added to the written file as the layer "Splats" (passes Combined and Depth).

The meshes' render is read and the result written by `layers`; a render that cannot
compose its splats fails loudly (`failures`); what a render knows between handler calls
is `state.current`.

The engine also renders on its own: with "Gaussian Splats" as the scene's render engine (the
"Render splats only" button), only the splats are rendered, over the world colour or over
transparency, with no mesh render at all.
"""

from __future__ import annotations

import functools
import threading
import time
import traceback

import bpy
import numpy as np
from bpy.app.handlers import persistent

from ...core.images import exr_layers
from ...core.render.renderer import release_buffers
from ...core.render.composite import (
    FAR,
    Region,
    apply_shadow_catcher,
    compose,
    embed,
    prepare,
    render_region,
    splat_layer,
)
from . import compositor_bridge as bridge
from . import state
from ..camera_adapter import frame_size, render_problem
from .compositor_bridge import ENGINE_ID
from ..registration import module_registration
from .failures import (
    fail_render,
    remove_failed_file,
    render_blockers,
    report_in_window,
    set_aside_outputs,
    settle_outputs,
)
from .layers import (
    frame_target,
    pass_image,
    read_render_layer,
    reads_render_cache,
    splat_passes,
    wants_splat_passes,
    world_colour,
    write_result,
    written_file,
)
from .state import capture_frame, render_border, settings_of

last_stats: dict[str, float] = {}       # the last composed frame: timings (ms) and counts


def _print_stats(stats: dict) -> None:
    if bpy.app.background:
        parts = ", ".join(f"{k[:-3]} {v:.0f}" for k, v in stats.items() if k.endswith("_ms"))
        print(f"Gaussian splats: {int(stats.get('gaussians', 0)):,} splats, "
              f"{int(stats.get('width', 0))}x{int(stats.get('height', 0))}: {parts} ms", flush=True)


class _Preparing:
    """`composite.prepare` of a frame's splats on a thread of its own (the native call releases
    the GIL, so it runs beside Blender's work on the main thread); `result()` waits for it and
    gives (frame, prepared, ms waited), or raises what it raised."""

    def __init__(self, frame, options: dict) -> None:
        self.frame, self._prepared, self._error = frame, None, None
        self._thread = threading.Thread(target=self._run, args=(options,), daemon=True,
                                        name="splat prepare")
        self._thread.start()

    @classmethod
    def start(cls, frame, scene, settings) -> _Preparing | None:
        """Started for a frame that will be composed in display sRGB; else None."""
        if (frame is None or frame.camera is None or len(frame.gaussians) == 0
                or not settings.enabled or scene.render.engine == ENGINE_ID
                or frame.color_space != "SRGB" or state.current.errors):
            return None
        options = frame.render_options()
        del options["color_space"]
        return cls(frame, options)

    def _run(self, options: dict) -> None:
        try:
            self._prepared = prepare(self.frame.gaussians, self.frame.camera, **options)
        except BaseException as error:  # handed to the engine thread by result()
            self._error = error

    def join(self) -> None:
        self._thread.join()

    def result(self):
        start = time.perf_counter()
        self._thread.join()
        if self._error is not None:
            raise self._error
        return self.frame, self._prepared, 1000 * (time.perf_counter() - start)


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
            fail_render(bpy.data.scenes.get(state.current.scene or "") or depsgraph.scene,
                        str(error) if str(error) in state.current.errors else message,
                        "compose")

    def _compose_for_bridge(self) -> None:
        start = time.perf_counter()
        scene_name = state.current.scene
        main = bpy.data.scenes.get(scene_name) if scene_name else None
        if main is None:
            raise RuntimeError("the splat composite was rendered outside a render of a scene")
        layer_name = bridge.bridge_view_layer(main) or main.view_layers[0].name
        settings = settings_of(main)
        # The Gaussians' half of the composite needs no mesh: it runs on a thread (in native code,
        # without the GIL) while Blender writes the mesh render out for us to read.
        preparing = _Preparing.start(state.current.frames.get((main.name, layer_name)),
                                     main, settings)
        try:
            mesh_rgba, mesh_depth, timings = read_render_layer(main, layer_name)
        except BaseException:
            if preparing is not None:
                preparing.join()  # (its own error, if any, would hide this one)
            raise
        prepared_frame, prepared, wait_ms = preparing.result() if preparing else (None,) * 3
        layer_name = timings.pop("layer")
        shadow = timings.pop("shadow")
        full = frame_size(main.render)
        region = render_region(*full, render_border(main.render))
        height, width = mesh_depth.shape
        origin = frame_target((width, height), full, region)
        frame = state.current.frames.get((main.name, layer_name))
        stats = {"width": width, "height": height, "gaussians": 0, **timings}
        for warning in (frame.warnings if frame is not None else ()):
            print(f"Gaussian splats: {warning}")
        if frame is not None and frame.frame != main.frame_current:
            print(f"Gaussian splats: the splats were gathered at frame {frame.frame}, the render "
                  f"is of frame {main.frame_current}")
        if state.current.errors:  # the render already failed (cancelled if it could be)
            raise RuntimeError(state.current.errors[-1])
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
            if prepared_frame is not frame:  # another view layer was rendered (rare)
                prepared = wait_ms = None
            composed = compose(frame.gaussians, frame.camera, mesh_rgba, mesh_depth,
                               out=pass_image(full[1], full[0]), prepared=prepared,
                               with_depth=bridge.uses_depth(main), coverage=frame.coverage,
                               **frame.render_options())
            mesh_rgba = mesh_depth = None  # not needed any more: a lower peak while writing
            rgba = composed.rgba[origin.slices()]
            depth = None if composed.depth is None else composed.depth[origin.slices()]
            native_ms = composed.stats.get("native_ms", composed.stats.get("ms_total", 0.0))
            if wait_ms is not None:  # only the wait for the thread counts, and the tile pass
                stats["prepared_ms"] = prepared.stats["ms_total"]
                native_ms += wait_ms - prepared.stats["ms_total"]
            stats.update(gaussians=len(frame.gaussians), reused=frame.reused,
                         gather_ms=frame.gather_ms, native_ms=native_ms,
                         colour_ms=composed.stats.get("colour_ms", 0.0))
            if wants_splat_passes(main):
                state.current.pending_passes[main.name] = (
                    main.frame_current, splat_passes(frame, main, full, region))
        if shadow is not None and shadow.shape[:2] == rgba.shape[:2]:
            # Proxies (shadow catchers) are left out of the mesh layer; their shadows darken
            # the composite, splats included (docs/guide/meshes.md).
            rgba = apply_shadow_catcher(rgba, shadow)
        before_write = time.perf_counter()
        write_result(self, rgba, depth if bridge.uses_depth(main) else None, origin, full, region)
        if main.render.engine == ENGINE_ID:
            return  # the splats were rendered (and counted) by the scene's own render
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
        target = frame_target(size, full, region)
        background = None if scene.render.film_transparent else world_colour(scene)
        if frame.camera is None or len(frame.gaussians) == 0:
            rgba = np.zeros((target.height, target.width, 4), np.float32)
            if background is not None:
                rgba[..., :3], rgba[..., 3] = background, 1.0
            depth = np.full((target.height, target.width), FAR, np.float32)
        else:
            layer = splat_layer(frame.gaussians, frame.camera, background=background,
                                coverage=frame.coverage, **frame.render_options())
            rgba, depth = layer.rgba[target.slices()], layer.depth[target.slices()]
        write_result(self, rgba, depth, target, full, region)
        last_stats.clear()
        last_stats.update(width=target.width, height=target.height,
                          gaussians=len(frame.gaussians), gather_ms=frame.gather_ms,
                          total_ms=1000 * (time.perf_counter() - start))
        _print_stats(last_stats)


# ------------------------------------------------------------------------------- handlers
# The bridge is set up before any render: when a file loads, and when a scene gains splats.
# Render handlers do not make the helper scene (from Blender 5.1; see `_SET_UP_AT_RENDER`):
# Blender 5.2 crashes (SIGSEGV) when render_init makes it. Repairing the bridge node, its links
# and the helper's borrowed camera from render_init was tried on 5.2 and works, as do
# `use_render_cache` (read after render_init) and, for a failure, the scene's camera. (The
# segfaults 5.2.2 gave for saved scenes whose splat object was hidden or deleted came from
# the helper scene holding a camera object of its own; it borrows one now.)

@persistent
def _on_render_init(scene, _depsgraph=None) -> None:
    if bridge.is_helper(scene):
        return
    state.current.scene = scene.name
    state.current.frames.clear()
    state.current.pending_passes.clear()
    state.current.errors.clear()
    state.current.failed_frames.clear()
    state.current.frame_start_ns = time.time_ns()
    settings = settings_of(scene)
    if not settings.enabled or scene.render.engine == ENGINE_ID:
        if bridge.bridge_node(scene) is not None:  # the helper passes the meshes through
            _read_through_render_cache(scene)
        return
    try:
        node = bridge.bridge_node(scene)
        if node is None and not bridge.has_splats(scene):
            return
        if node is not None and bridge.is_helper(node.scene):
            bridge.attach_camera(node.scene)  # a script emptied bpy.data.objects (a pointer)
        if _can_set_up_at_render() and bridge.ensure_bridge(scene):
            print(f"Gaussian splats: compositor bridge set up for scene {scene.name!r}")
        blockers = render_blockers(scene)
        problem = render_problem(scene.camera, scene.render.engine)
        if problem:  # a camera the splats cannot go through: stop before the meshes render
            blockers.append(problem)
        if blockers:
            fail_render(scene, "; ".join(blockers), "init")
            return
        _read_through_render_cache(scene)
    except Exception as error:
        traceback.print_exc()
        fail_render(scene, f"cannot prepare the splat composite: {error}", "init")


def _read_through_render_cache(scene) -> None:
    """Where the helper engine reads the meshes' render from the render cache (`layers`), turn
    the scene's cache on for this render (Blender reads the flag when the render starts, after
    render_init); `_on_render_done` puts the user's value back."""
    if reads_render_cache():
        state.current.cache_restore[scene.name] = scene.render.use_render_cache
        if not scene.render.use_render_cache:
            scene.render.use_render_cache = True


@persistent
def _on_render_pre(scene, _depsgraph=None) -> None:
    if bridge.is_helper(scene):
        return
    state.current.frame_start_ns = time.time_ns()
    if state.current.scene == scene.name and settings_of(scene).enabled:
        set_aside_outputs(scene)


@persistent
def _on_frame_change(scene, depsgraph=None) -> None:
    rendering = state.current.scene
    if (depsgraph is None or rendering is None or scene.name != rendering
            or depsgraph.mode != "RENDER" or bridge.is_helper(scene)
            or not settings_of(scene).enabled or scene.render.engine == ENGINE_ID
            or state.current.errors):
        return
    try:
        frame = capture_frame(scene, depsgraph)
    except Exception as error:
        traceback.print_exc()
        fail_render(scene, f"the splats could not be gathered: {error}", "frame")
        return
    state.current.frames[(scene.name, depsgraph.view_layer.name)] = frame



@persistent
def _on_render_write(scene, _depsgraph=None) -> None:
    if bridge.is_helper(scene):
        return
    if scene.frame_current in state.current.failed_frames:
        remove_failed_file(scene)
        return
    pending = state.current.pending_passes.pop(scene.name, None)
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
        remove_failed_file(scene)


@persistent
def _on_render_done(scene, _depsgraph=None) -> None:
    if bridge.is_helper(scene):
        return
    users_cache = state.current.cache_restore.pop(scene.name, None)
    if users_cache is not None and scene.render.use_render_cache != users_cache:
        scene.render.use_render_cache = users_cache
    camera = state.current.camera_restore.pop(scene.name, None)
    if camera is not None:
        scene.camera = camera
    settle_outputs()
    release_buffers()  # a 1M-Gaussian frame keeps ~130 MB of working memory for the next one
    state.current.scene = None
    state.current.frames.clear()
    state.current.pending_passes.clear()
    if state.current.errors and not bpy.app.background:
        message = state.current.errors[-1]
        bpy.app.timers.register(lambda: report_in_window(message), first_interval=0.0)


_object_counts: dict[str, int] = {}
_helper_made_for: set[str] = set()   # scenes whose helper scene was made in the last update

# Blender up to 5.0 takes the bridge being set up from render_init (a script that adds splats
# and renders at once relies on it); 5.2 crashes when render_init makes the helper scene, so
# from 5.1 on a render repairs the bridge (its node, its links, the helper's camera) only when
# the helper scene is there, and otherwise fails with what to do.
_SET_UP_AT_RENDER = bpy.app.version < (5, 1, 0)


def _can_set_up_at_render() -> bool:
    return _SET_UP_AT_RENDER or bridge.helper_scene(create=False) is not None


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
    if not waiting and _bridge_broken(scene):
        _object_counts.pop(scene.name, None)   # repair it as if the scene had just gained splats
        waiting = True
    if not waiting and not depsgraph.id_type_updated("OBJECT"):
        return
    count = len(scene.objects)
    if not waiting and _object_counts.get(scene.name) == count:
        return
    _object_counts[scene.name] = count
    if not settings_of(scene).enabled or (bridge.bridge_node(scene) is not None
                                          and not _bridge_broken(scene)) \
            or scene.render.engine == ENGINE_ID or not bridge.has_splats(scene):
        return
    if not bpy.app.background:
        name = scene.name
        bpy.app.timers.register(lambda: set_up_bridge_later(name), first_interval=0.0)
    elif _SET_UP_AT_RENDER:
        return  # the render sets it up (a script's scene changes nothing before)
    elif bridge.helper_scene(create=False) is None:
        bridge.helper_scene()
        _helper_made_for.add(scene.name)
    else:
        _helper_made_for.discard(scene.name)
        set_up_bridge_later(scene.name)


def _bridge_broken(scene) -> bool:
    """The scene has a bridge whose helper data is gone: the helper scene deleted (the node
    points nowhere) or its borrowed camera deleted (a script emptied `bpy.data.objects`).
    Cheap: it runs on every viewport depsgraph update."""
    node = bridge.bridge_node(scene)
    if node is None or not settings_of(scene).enabled:
        return False
    if not bridge.is_helper(node.scene):
        return True
    if node.scene.camera is None:
        bridge.attach_camera(node.scene)   # a pointer: no need to wait for a later update
    return False


def _rendering() -> bool:
    return state.current.scene is not None or (hasattr(bpy.app, "is_job_running")
                                               and bpy.app.is_job_running("RENDER"))


def set_up_bridge_later(scene_name: str) -> float | None:
    """Timer: bridge the scene once no render runs, if it has splats."""
    scene = bpy.data.scenes.get(scene_name)
    if _rendering():
        return 0.5  # never while a render runs: try again when it is done
    if scene is not None and scene.render.engine != ENGINE_ID and settings_of(scene).enabled \
            and (bridge.bridge_node(scene) is None or _bridge_broken(scene)) \
            and bridge.has_splats(scene):
        try:
            bridge.ensure_bridge(scene)
        except Exception:
            traceback.print_exc()
    return None


# Why the UI sets the bridge up as it does (issue 36, benchmarks/bench_ui_new_object_blender.sh):
# Blender answers any change to the file by restarting the 3D view's anti-aliasing, a run of
# about 8 redraws (0.1-0.15 s each with software OpenGL on an idle 2-core machine, 0.15-0.3 s
# beside a CPU-bound process), and setting a scene's render engine (the helper scene's) resets
# every viewport engine, which makes the next redraw up to 0.15 s longer still. So the helper scene
# is made where a run comes anyway (a COLMAP import, else the click that starts a job), and the
# bridge itself in the same update as a job's first splats: their run, not one of its own.

def make_helper_ahead(scene) -> None:
    """`scene` is about to get splats (a COLMAP scene imported to train, a job about to add
    them): make the F12 helper scene now (see above). Nothing for the splats-only engine or
    with Composite Splats off; never while a render runs (then from a timer)."""
    if scene is None or scene.render.engine == ENGINE_ID or not settings_of(scene).enabled \
            or bridge.helper_scene(create=False) is not None:
        return
    if _rendering():
        name = scene.name
        bpy.app.timers.register(lambda: make_helper_ahead(bpy.data.scenes.get(name)),
                                first_interval=0.5)
        return
    bridge.helper_scene()


def bridge_new_splats(obj) -> None:
    """A job has just written splats into `obj` from the UI: bridge its scenes in this same
    update (see above), not from the timer of the depsgraph update that follows."""
    try:
        scenes = obj.users_scene if obj is not None else ()
    except (AttributeError, ReferenceError):  # not an object, or one removed meanwhile
        return
    for scene in scenes:
        retry = set_up_bridge_later(scene.name)
        if retry is not None:
            bpy.app.timers.register(functools.partial(set_up_bridge_later, scene.name),
                                    first_interval=retry)


@persistent
def _on_load_post(*_args) -> None:
    """A file opened (also `blender -b file.blend -a`, before it renders): bridge its scenes."""
    _object_counts.clear()
    _helper_made_for.clear()
    try:
        bridge.tidy_legacy_helpers()
    except Exception:
        traceback.print_exc()
    for scene in list(bpy.data.scenes):
        if not bridge.is_helper(scene):
            bridge.switch_on_layers(scene)
            set_up_bridge_later(scene.name)


_compositing_off: list[str] = []   # scenes whose Compositing is on only in the file being saved
_unbridged: list[str] = []         # scenes saved without their bridge (Blender's own splats only)


@persistent
def _on_save_pre(*_args) -> None:
    """Files are saved with their bridge, with Compositing on, their view layers switched off
    and without the helpers' borrowed cameras (see `compositor_bridge`): a Blender without the
    add-on then refuses to render them, at once.
    Blender up to 5.0 sets the bridge up only when a render starts, so a file a script saves
    right after adding splats gets it here (5.1+ has it from the scene's update). Compositing
    switched off by hand would let such a Blender skip the compositor, and with it the helper
    scene's error, and write frames without splats; it is on in the file only (save_post puts
    the session's value back: a job that renders with it off, such as Bake to Splats, goes on
    as it was).

    A scene whose only splats are Blender's own (5.3's splat point clouds) is saved without its
    bridge: Blender renders those by itself, so the file stays Blender's (`ownership` saves the
    clouds as Blender made them); save_post bridges it again."""
    _compositing_off.clear()
    _unbridged.clear()
    for scene in [s for s in bpy.data.scenes if not bridge.is_helper(s)]:
        try:
            if not (settings_of(scene).enabled and scene.render.engine != ENGINE_ID
                    and bridge.has_splats(scene)):
                continue
            if not bridge.has_splats(scene, blenders=False):
                if bridge.remove_bridge(scene):
                    _unbridged.append(scene.name)
                continue
            if _SET_UP_AT_RENDER and bridge.bridge_node(scene) is None:
                bridge.ensure_bridge(scene)
            if bridge.bridge_node(scene) is not None:
                if not scene.render.use_compositing:
                    scene.render.use_compositing = True
                    _compositing_off.append(scene.name)
                bridge.switch_off_layers(scene)
        except Exception:   # never keep a file from being saved
            traceback.print_exc()
    bridge.detach_cameras()


@persistent
def _on_save_post(*_args) -> None:
    for scene in bpy.data.scenes:
        if bridge.is_helper(scene):
            bridge.attach_camera(scene)
        else:
            bridge.switch_on_layers(scene)
    for name in _compositing_off:
        if name in bpy.data.scenes:
            bpy.data.scenes[name].render.use_compositing = False
    _compositing_off.clear()
    for name in _unbridged:
        if name in bpy.data.scenes:
            try:
                bridge.ensure_bridge(bpy.data.scenes[name])
            except Exception:
                traceback.print_exc()
    _unbridged.clear()


_HANDLERS = (
    ("depsgraph_update_post", _on_depsgraph_update),
    ("save_pre", _on_save_pre),
    ("save_post", _on_save_post),
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


_register, _unregister = module_registration((SplatRenderEngine,), handlers=_HANDLERS)


def _shared_panel_engines():
    """The COMPAT_ENGINES sets of `_SHARED_PANELS` this Blender has."""
    for name in _SHARED_PANELS:
        engines = getattr(getattr(bpy.types, name, None), "COMPAT_ENGINES", None)
        if isinstance(engines, set):
            yield engines


def register() -> None:
    _register()
    for engines in _shared_panel_engines():
        engines.add(ENGINE_ID)


def unregister() -> None:
    for engines in _shared_panel_engines():
        engines.discard(ENGINE_ID)
    _unregister()
