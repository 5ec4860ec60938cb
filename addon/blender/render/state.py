"""The state of the render in progress, and what each of its frames renders.

`current` is the one place the render hooks (`hooks`), the reading of the meshes'
render (`layers`) and the failure handling (`failures`) share what they know
about the render between Blender's handler calls.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ...core.cameras import Camera, image_coverage
from ...core.gaussians import Gaussians
from ..sources import gather
from ..camera_adapter import camera_of, near_of, render_problem
from ..threads import scene_threads
from .compositor_bridge import ENGINE_ID


@dataclass
class FrameSplats:
    """What one frame renders: gathered from the render's own depsgraph."""

    scene: str
    view_layer: str
    frame: int
    gaussians: Gaussians
    camera: Camera | None        # the full frame; None: no camera (Blender renders nothing)
    antialiased: bool
    color_space: str
    sh_degree: int
    near: float
    threads: int
    gather_ms: float
    warnings: list[str] = field(default_factory=list)
    reused: int = 0              # splat objects whose Gaussians came from the gather cache
    coverage: np.ndarray | None = None  # the pixels the camera shows (None: all; the camera's
                                        # image_coverage, found with it)

    def render_options(self) -> dict:
        return dict(color_space=self.color_space, antialiased=self.antialiased, near=self.near,
                    sh_degree=self.sh_degree, threads=self.threads)


class RenderState:
    """What the render in progress knows (render_init..render_complete/cancel)."""

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
        self.set_aside: dict[str, str] = {}    # output file -> where its previous copy waits


current = RenderState()


def settings_of(scene):
    return scene.splat_render


def render_border(render) -> tuple[float, float, float, float] | None:
    if not render.use_border:
        return None
    return (render.border_min_x, render.border_max_x, render.border_min_y, render.border_max_y)


def render_threads(scene) -> int:
    """Threads for a final render's splats (`blender/threads.py`): the add-on's own setting, or
    with 0 as many as Blender renders with (Render > Performance > Threads; `blender -t N` on a
    shared farm machine), so that a worker limited to N threads composes its splats on N too."""
    return scene_threads(scene, beside_ui=False)


def capture_frame(scene, depsgraph) -> FrameSplats:
    """Gather the splats and the camera a render depsgraph shows (see `hooks`)."""
    settings = settings_of(scene)
    start = time.perf_counter()
    result = gather.gather(depsgraph)
    warnings = list(result.warnings)
    antialiased = {"OBJECT": result.antialiased, "ON": True, "OFF": False}[settings.antialiased]
    spaces = {b.color_space for b in result.batches}
    reused = result.cache_hits
    camera = None
    near = settings.near
    camera_obj = depsgraph.scene.camera
    if camera_obj is None:
        warnings.append("the scene has no camera")
    else:
        camera_obj = camera_obj.evaluated_get(depsgraph)
        engine = depsgraph.scene.render.engine
        problem = render_problem(camera_obj, None if engine == ENGINE_ID else engine)
        if problem:  # never a finished frame without its splats: the render fails
            raise ValueError(problem)
        camera = camera_of(camera_obj, depsgraph.scene_eval.render)
        near = near_of(camera_obj, settings.near)
    if len(spaces) > 1:
        warnings.append("splat objects disagree on the colour space: composing in sRGB")
    color_space = "LINEAR" if spaces == {"LINEAR"} else "SRGB"
    gaussians = result.gaussians
    return FrameSplats(scene.name, depsgraph.view_layer.name, scene.frame_current, gaussians,
                       camera, antialiased, color_space,
                       min(settings.sh_degree, gaussians.degree), near,
                       render_threads(scene),
                       1000 * (time.perf_counter() - start), warnings, reused,
                       None if camera is None else image_coverage(camera))
