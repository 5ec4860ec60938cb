"""The meshes' render layer, round trip: what the helper engine reads from the scene's render
and writes back (see `hooks` for how a frame is made).

Reading the render, two ways (`reads_render_cache` chooses when the render starts):
- In the UI, and wherever there is no "Render Result" image (a command-line render of a file
  that never showed one), the scene's render cache (`render.use_render_cache`, switched on for
  the render and back to the user's value after it) writes the meshes' render as an EXR, and it
  is read from Blender's cache path. In the UI the render runs in a job thread while the main
  thread draws the Render Result; `Image.save_render` of that image from the render thread can
  deadlock with it (Debian's Blender 5.2.2 under Xvfb hung inside it twice in about 200 F12s,
  its main thread waiting on a mutex; docs/benchmarks/render_with_meshes.md).
- In background renders (`blender -b`, the `bpy` module), where the render runs on the main
  thread and nothing draws: `Image.save_render` of the Render Result to an uncompressed float
  multilayer EXR in a private temporary folder (the output format is switched for that one
  call and put back), the faster way: the file is in memory and read in place.
Writing: the engine's render result, and the splat layer for multilayer EXR files.

Why a file: Python has no other way to the render's pixels while it runs. The Render Result
image has no pixels in Python (`Image.pixels` is empty, `foreach_get` gives nothing: measured in
bpy 5.0.1), and a RenderEngine reaches only its own result's passes, not the scene's engine's.
The EXR goes to /dev/shm where there is one (memory, no disk), uncompressed float and
interleaved (one part holding every channel: Blender 5.0 writes the 1280x720 Combined and Depth
in 18 ms so, 23 ms as one part per pass, at load 7). `Image.save_render` is most of what
reading costs, and nothing in it can be left out: it writes only the passes there are, and no
"Composite" layer while the frame renders. Our own file is mapped, not read, and the colour is
a read-only strided view of its planar rows (`exr_layers.find_pass`), which the colour
conversion reads where it lies: no copy of the frame is made to read it.

Writing back needs no file. The composite goes straight into the helper render's own result
(`get_result`; a full-frame `begin_result`/`end_result` would allocate a second result and merge
it: 8 of the 11 ms writing took at 1280x720), from a buffer whose rows run bottom to top as a
pass's do (`pass_image`: `compose` decodes into it), with one `RenderPass.rect.foreach_set`.
The Depth pass is filled only when the compositor reads it (`compositor_bridge.uses_depth`).
"""

from __future__ import annotations

import atexit
import contextlib
import hashlib
import os
import shutil
import tempfile
import time

import bpy
import numpy as np

from ...core.images import exr_layers, exr_scanlines
from ...core.render.composite import FAR, Region, splat_layer
from . import state
from .state import FrameSplats, settings_of

_temp_dir: str | None = None


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
    """Switch the scene's output format to uncompressed float multilayer EXR, interleaved (one
    part, as Blender 4.x always writes it), then back."""
    settings = scene.render.image_settings
    saved = [(key, getattr(settings, key)) for key in _FORMAT_KEYS if hasattr(settings, key)]
    try:
        if hasattr(settings, "media_type"):
            settings.media_type = "MULTI_LAYER_IMAGE"
        else:  # Blender 4.x
            settings.file_format = "OPEN_EXR_MULTILAYER"
        settings.color_depth = "32"
        settings.exr_codec = "NONE"
        if hasattr(settings, "use_exr_interleave"):  # Blender 5.0+
            settings.use_exr_interleave = True
        if hasattr(settings, "color_management"):
            settings.color_management = "FOLLOW_SCENE"
        yield
    finally:
        for key, value in saved:
            with contextlib.suppress(TypeError, AttributeError, ValueError):
                setattr(settings, key, value)


def render_result_image():
    return next((image for image in bpy.data.images if image.type == "RENDER_RESULT"), None)


def reads_render_cache() -> bool:
    """Whether the render about to start is read from Blender's render cache file rather than
    saved from the Render Result (see the module docstring)."""
    return (not bpy.app.background or render_result_image() is None
            or state.current.force_cache_file)


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
    engine rendered for view layer `layer`, rows top to bottom, read while the render runs
    (read-only views of the file's rows: no copy); and timings (ms), with "layer": the view
    layer read (another one if `layer` was not rendered); "save_ms" only where the render was
    saved from the Render Result, not read from the render cache."""
    timings = {}
    own_file = scene.name not in state.current.cache_restore  # (the cache is on: render_init)
    if not own_file:
        path = cache_file_path(scene)
        since = state.current.frame_start_ns - 50_000_000
        if not os.path.exists(path) or os.stat(path).st_mtime_ns < since:
            raise RuntimeError(f"cannot read the render: no fresh render cache file at {path}")
    else:
        start = time.perf_counter()
        path = os.path.join(_private_dir(), f"render-{abs(hash(scene.name))}.exr")
        image = render_result_image()
        if image is None:
            raise RuntimeError("cannot read the render: the Render Result image is gone")
        with _float_exr_output(scene):
            image.save_render(path, scene=scene)
        timings["save_ms"] = 1000 * (time.perf_counter() - start)
    start = time.perf_counter()
    try:
        # No OpenImageIO (Blender's Python may lack it). Our own file is mapped, not read: no
        # one rewrites it, and it goes at once (POSIX keeps a deleted file's mapped pages).
        channels = exr_scanlines.read_channels(path, mapped=own_file and os.name == "posix")
    finally:
        if own_file:
            # Our own copy, read into memory: /dev/shm is RAM, so it goes now, not at exit
            # (a process that is killed never gets there).
            with contextlib.suppress(OSError):
                os.remove(path)
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
    return rgba, depth, timings


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


def frame_target(size: tuple[int, int], full: tuple[int, int], region: Region) -> Region:
    """Which part of the frame a render result of `size` (width, height) covers."""
    if size == full:
        return Region(0, 0, *full)
    if size == (region.width, region.height):
        return region
    raise RuntimeError(f"unexpected render result size {size[0]}x{size[1]} for a "
                       f"{full[0]}x{full[1]} frame (border {region})")


def pass_image(height: int, width: int) -> np.ndarray:
    """A new (H, W, 4) float32 image, rows top to bottom, stored bottom to top as a render pass
    holds them: `write_result` fills a pass from it as it is, with no flipped copy."""
    return np.empty((height, width, 4), np.float32)[::-1]


def _set_pass(render_pass, pixels: np.ndarray) -> None:
    """Fill a RenderPass from (H, W[, C]) float32 rows top to bottom (a pass stores them bottom
    to top: flipped here unless stored that way, see `pass_image`). `foreach_set` copies the
    buffer in one go: about 1 ms for 1280x720 RGBA, where assigning `rect` a nested sequence
    takes a second."""
    render_pass.rect.foreach_set(np.ascontiguousarray(pixels[::-1], np.float32).reshape(-1))


def write_result(engine, rgba: np.ndarray, depth: np.ndarray | None, origin: Region,
                  full: tuple[int, int], region: Region) -> None:
    """Fill the engine's render result from `rgba`, `depth` (rows top to bottom) that cover
    `origin` of the full frame (depth None: the Depth pass stays empty), straight into the
    render's own result (see the module docstring). Blender allocates a result's passes on the
    first merge, so a 1x1 result is merged first."""
    engine.end_result(engine.begin_result(0, 0, 1, 1))
    result = engine.get_result()
    target = frame_target((result.resolution_x, result.resolution_y), full, region)
    if target != origin:  # a full-frame image for a border render: keep the border part
        rows = slice(target.y - origin.y, target.y - origin.y + target.height)
        cols = slice(target.x - origin.x, target.x - origin.x + target.width)
        rgba = rgba[rows, cols]
        depth = None if depth is None else depth[rows, cols]
    layer = result.layers[0]
    _set_pass(layer.passes["Combined"], rgba)
    depth_pass = layer.passes.get("Depth")
    if depth_pass is not None and depth is not None:
        _set_pass(depth_pass, depth)


def wants_splat_passes(scene) -> bool:
    settings = scene.render.image_settings
    multilayer = (getattr(settings, "media_type", None) == "MULTI_LAYER_IMAGE"
                  or settings.file_format == "OPEN_EXR_MULTILAYER")
    return multilayer and settings_of(scene).splat_passes


def splat_passes(frame: FrameSplats, scene, full: tuple[int, int], region: Region):
    """The splat layer alone, over the area of the file Blender writes."""
    layer = splat_layer(frame.gaussians, frame.camera, coverage=frame.coverage,
                        **frame.render_options())
    if scene.render.use_border and scene.render.use_crop_to_border:
        layer.rgba, layer.depth = layer.rgba[region.slices()], layer.depth[region.slices()]
    elif scene.render.use_border:  # Blender leaves the outside of a border empty
        inside = np.zeros(layer.depth.shape, bool)
        inside[region.slices()] = True
        layer.rgba[~inside] = 0.0
        layer.depth[~inside] = FAR
    return layer


def output_paths(scene) -> list[str]:
    """Where Blender writes the current frame's image: as an animation frame, and as a still
    (`render(write_still=True)`), when those differ."""
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
    return candidates


def written_file(scene) -> str | None:
    """The image file Blender has just written for the current frame (a still or an animation
    frame: both names are tried, the one written since the frame began wins)."""
    fresh = [(os.stat(p).st_mtime_ns, p) for p in output_paths(scene) if os.path.exists(p)
             and os.stat(p).st_mtime_ns >= state.current.frame_start_ns - 50_000_000]
    return max(fresh)[1] if fresh else None
