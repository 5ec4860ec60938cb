"""The F12 path and the viewport's draw, walked call by call through the add-on's modules.

    .venv/bin/python scripts/walk.py [--verbose]

Builds a scene holding one add-on splat object and one point cloud with Blender 5.3's splat
attributes (in a bpy before 5.3 the type test is stood in for, as tests/blender/blender_splats/
does), then traces (`sys.setprofile`), with the gather cache cold and again warm:

  - F12: `hooks.SplatRenderEngine._render_splats_only` ("Render splats only": the whole of F12's
    splat side, without the meshes' render), run by `bpy.ops.render.render`;
  - the viewport: `viewport.draw_view` for a stand-in 3D view, the render it asks for run in
    the same thread (`render_view`; drawing the image needs a GPU and is left out).

Rooms are those of docs/architecture.md (a folder under core/ or blender/, or a module directly
in addon/, core/ or blender/) but core/gaussians.py (the data every room passes along);
splatcore, numpy and bpy are not counted. A *stay* begins each time a call enters a room from
another one; a return to the caller continues the caller's stay, and the caller's next call
into that same room (nothing else entered from it between) continues that stay too. A *climb*
is a call into a room first entered earlier in the walk than the calling one (back up the
path). Printed per walk: stays, climbs, rooms, the stays per room and, with --verbose, every
stay (the function that entered it, indented by depth; a climb marked ^).
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import numpy as np  # noqa: E402

ADDON = str(ROOT / "addon") + "/"
# The data carried along the walk, not a room on it: `Gaussians` (its properties, `subset`,
# `sh_count`...) is used by every room.
PASSED_ALONG = {"core/gaussians.py"}


def room_of(filename: str) -> str | None:
    """The room (docs/architecture.md: a folder under core/ or blender/, or a module directly
    in addon/, core/ or blender/) a source file belongs to; None outside addon/."""
    if not filename.startswith(ADDON):
        return None
    parts = filename[len(ADDON):].split("/")
    room = "/".join(parts[:2]) + "/" if len(parts) > 2 else "/".join(parts)
    return None if room in PASSED_ALONG else room


class Walk:
    """The stays and climbs of the calls made inside one function (the walk's start)."""

    def __init__(self) -> None:
        self.stack: list[int | None] = []   # per Python frame: the stay it runs in (None: none)
        # per stay: room, module.function that entered it, climb, the stay it was entered from
        self.stays: list[tuple[str, str, bool, int | None]] = []
        self.last_entered: dict[int | None, int] = {}  # stay -> the last stay entered from it
        self.first: dict[str, int] = {}

    def _current(self) -> int | None:
        return next((s for s in reversed(self.stack) if s is not None), None)

    def profile(self, frame, event, _arg) -> None:
        if event == "call":
            room = room_of(frame.f_code.co_filename)
            caller = self._current()
            stay = caller
            if room is not None and (caller is None or room != self.stays[caller][0]):
                last = self.last_entered.get(caller)
                if last is not None and self.stays[last][0] == room:
                    stay = last   # the caller's next call goes to the same room: the same stay
                else:
                    climb = caller is not None and \
                        self.first.get(room, 1 << 30) < self.first[self.stays[caller][0]]
                    self.first.setdefault(room, len(self.first))
                    module = frame.f_code.co_filename[len(ADDON):-3].replace("/", ".")
                    self.stays.append((room, f"{module}.{frame.f_code.co_name}", climb, caller))
                    stay = self.last_entered[caller] = len(self.stays) - 1
            self.stack.append(stay)
        elif event == "return" and self.stack:
            self.stack.pop()

    def _depth(self, stay: int) -> int:
        depth = 0
        while (stay := self.stays[stay][3]) is not None:
            depth += 1
        return depth

    def trace(self, function, *args, **kwargs):
        sys.setprofile(self.profile)
        try:
            return function(*args, **kwargs)
        finally:
            sys.setprofile(None)

    def counts(self) -> tuple[int, int]:
        """(stays, climbs)."""
        return len(self.stays), sum(s[2] for s in self.stays)

    def report(self, title: str, verbose: bool) -> None:
        per_room: dict[str, int] = {}
        for module, *_ in self.stays:
            per_room[module] = per_room.get(module, 0) + 1
        stays, climbs = self.counts()
        print(f"{title}: {stays} stays in {len(per_room)} rooms, {climbs} climbs")
        print("    " + ", ".join(f"{m} {n}" for m, n in per_room.items()))
        if verbose:
            for index, (_, function, climb, _) in enumerate(self.stays):
                print(f"      {'^' if climb else ' '} {'  ' * self._depth(index)}{function}")


@contextlib.contextmanager
def stand_in():
    """Before 5.3, a point cloud holding `radiance:base` counts as Blender's splats (as
    tests/blender/blender_splats/test_blender_splats_bpy.py has it)."""
    import bpy

    from addon.blender.blender_splats import data

    real = data.is_blender_splat_data
    if not data.supported():
        data.is_blender_splat_data = lambda d: isinstance(d, bpy.types.PointCloud) \
            and "radiance:base" in d.attributes
    try:
        yield
    finally:
        data.is_blender_splat_data = real


def build_scene():
    """An empty scene with an add-on splat object (2000 splats), a point cloud holding
    Blender's splat attributes (1000) and a 64x48 camera; returns the camera."""
    import bpy_support as bs
    from bpy_support import bpy
    from scenes import random_gaussians

    from addon.blender import splat_object
    from addon.blender.blender_splats import data
    from addon.core.blender_splats import attributes

    bs.reset_scene()
    rng = np.random.default_rng(0)
    obj = splat_object.create_splat_object(random_gaussians(rng, 2000, 1, radius=1.0), "Splats")
    obj.location = (0.5, 0.0, 0.0)
    gaussians = random_gaussians(rng, 1000, 1, radius=1.0)
    pointcloud = data._sized_pointcloud("Cloud", len(gaussians))
    for name, values in attributes.attributes_from_gaussians(gaussians).items():
        data_type = attributes.REQUIRED.get(name, attributes.SH_TYPE)[0]
        if data_type == "FLOAT4" and not data.supported():
            data_type = "FLOAT_COLOR"
        attribute = pointcloud.attributes.get(name) or pointcloud.attributes.new(
            name, data_type, "POINT")
        attribute.data.foreach_set(data._KEYS[data_type][0],
                                   np.ascontiguousarray(values).reshape(-1))
    if data.supported():
        pointcloud.type = data.GAUSSIAN_SPLAT
    cloud = bpy.data.objects.new("Cloud", pointcloud)
    bpy.context.scene.collection.objects.link(cloud)
    cloud.location = (-0.5, 0.0, 0.0)
    return bs.add_camera(width=64, height=48)


def f12_walks() -> dict[str, Walk]:
    """F12 ("Render splats only") of the scene, walked with the gather cache cold, then warm."""
    import bpy

    from addon.blender.render import hooks
    from addon.blender.render.compositor_bridge import ENGINE_ID
    from addon.blender.sources import gather

    bpy.context.scene.render.engine = ENGINE_ID
    engine = hooks.SplatRenderEngine
    original = engine._render_splats_only
    walks = {}
    for cache in ("cold", "warm"):
        if cache == "cold":
            gather.clear_cache()
        walk = walks[cache] = Walk()
        engine._render_splats_only = lambda self, depsgraph: walk.trace(original, self, depsgraph)
        try:
            bpy.ops.render.render()
        finally:
            engine._render_splats_only = original
        assert hooks.last_stats.get("gaussians") == 3000, hooks.last_stats
    return walks


def viewport_walks(camera) -> dict[str, Walk]:
    """The viewport's draw of a 160x120 view through `camera`, walked with the gather cache
    cold, then warm (the render it asks for run in this thread)."""
    import bpy
    import mathutils

    from addon.blender import viewport
    from addon.blender.sources import gather

    width, height = 160, 120
    depsgraph = bpy.context.evaluated_depsgraph_get()
    view = np.array(camera.matrix_world.inverted())
    window = np.array(camera.calc_matrix_camera(depsgraph, x=width, y=height))

    class Region:
        def __init__(self):
            self.width, self.height = width, height

        def as_pointer(self):
            return 4343

    context = type("Context", (), dict(
        scene=bpy.context.scene, region=Region(),
        space_data=type("Space", (), dict(type="VIEW_3D",
                                          shading=type("S", (), dict(type="SOLID"))()))(),
        region_data=type("RV3D", (), dict(view_matrix=mathutils.Matrix(view.tolist()),
                                          window_matrix=mathutils.Matrix(window.tolist())))(),
        evaluated_depsgraph_get=staticmethod(bpy.context.evaluated_depsgraph_get)))()
    rendered = []

    def submit(job):  # the worker's render, in this thread
        rendered.append(viewport.render_view(job.gaussians, job.camera, job.window_matrix,
                                             key=job.key, coarse=job.coarse, **job.options))

    original, shader = viewport.renderer.submit, viewport._shader
    viewport.renderer.submit = submit
    viewport._shader = lambda: None  # GPU work (none in background mode), not the add-on's walk
    walks = {}
    try:
        for cache in ("cold", "warm"):
            if cache == "cold":
                gather.clear_cache()
            viewport._views.clear()
            rendered.clear()
            walks[cache] = Walk()
            walks[cache].trace(viewport.draw_view, context)
            assert rendered, "the draw asked for no render"
    finally:
        viewport.renderer.submit, viewport._shader = original, shader
        viewport.renderer.forget(4343)
        viewport._views.clear()
    return walks


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--verbose", action="store_true", help="list every stay")
    args = parser.parse_args()
    with stand_in():
        camera = build_scene()
        for cache, walk in f12_walks().items():
            walk.report(f"F12 ({cache} cache)", args.verbose)
        for cache, walk in viewport_walks(camera).items():
            walk.report(f"viewport draw ({cache} cache)", args.verbose)


if __name__ == "__main__":
    main()
