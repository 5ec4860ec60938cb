"""Which representation a Blender 5.3 user gets by default: the add-on's splat object (a mesh) or
Blender's own splat point cloud. Times the same N Gaussians in both (process CPU and wall time).

Runs in bpy 5.3 with the extension installed (as tests/real_blender/splats53.py installs it):

    bpy313.sh 5.3.0 python /io/splats53/bench_blender_splats.py --work /io/splats53/work \\
        [--n 1000000] [--degree 3] [--zip ZIP]

Rows, for each representation:
  import           the add-on's importer (.ply of N random Gaussians) into that representation
  gather           world-space Gaussians for a render (uncached: a new depsgraph's first F12)
  gather, cached   the same again (the viewport's redraws, an animation's frames)
  F12              Cycles F12 (1 sample, 320x240) with the splats composed (the add-on renders both)
  crop             splat.crop of half the splats (the add-on's operator, Object Mode)
  edit mode        entering Edit Mode (mode_set EDIT), and leaving it (written back)
  select + delete  in Edit Mode: select all, delete (Blender's own operators)
  geometry nodes   a Transform Geometry modifier: evaluation after changing its offset
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

EXTENSION = "bl_ext.user_default.gaussian_splatting"


def ext(name: str):
    import importlib

    return importlib.import_module(f"{EXTENSION}.{name}")


def timed(function) -> tuple[float, float, object]:
    wall, cpu = time.perf_counter(), time.process_time()
    result = function()
    return time.perf_counter() - wall, time.process_time() - cpu, result


def random_gaussians(n: int, degree: int):
    import numpy as np

    Gaussians = ext("core.gaussians").Gaussians
    rng = np.random.default_rng(0)
    f = np.float32
    return Gaussians(rng.standard_normal((n, 3), dtype=f) * f(2), rng.uniform(-5, -2, (n, 3)).astype(f),
                     rng.standard_normal((n, 4), dtype=f), rng.standard_normal(n, dtype=f) * f(2),
                     rng.standard_normal((n, (degree + 1) ** 2, 3), dtype=f) * f(0.3))


def scene_for_f12(bpy, work: Path):
    import math

    scene = bpy.context.scene
    camera = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(camera)
    camera.location, camera.rotation_euler = (0, -12, 0), (math.pi / 2, 0, 0)
    scene.camera = camera
    scene.render.engine = "CYCLES"  # Workbench draws Blender's splat clouds itself (see the docs)
    scene.cycles.samples, scene.cycles.use_denoising = 1, False
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 320, 240, 100
    scene.render.filepath = str(work / "bench_f12.png")
    return scene


def geometry_nodes(bpy, obj):
    group = bpy.data.node_groups.new("Offset", "GeometryNodeTree")
    group.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    group.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    source, sink = group.nodes.new("NodeGroupInput"), group.nodes.new("NodeGroupOutput")
    transform = group.nodes.new("GeometryNodeTransform")
    group.links.new(source.outputs[0], transform.inputs[0])
    group.links.new(transform.outputs[0], sink.inputs[0])
    modifier = obj.modifiers.new("Offset", "NODES")
    modifier.node_group = group
    return transform


def bench(bpy, kind: str, path: Path, work: Path, n: int) -> dict[str, tuple[float, float]]:
    import numpy as np

    operators = ext("blender.io.operators")
    gather = ext("blender.sources.gather")
    rows = {}
    for obj in list(bpy.data.objects):
        bpy.data.objects.remove(obj)
    gather.clear_cache()
    wall, cpu, obj = timed(lambda: operators.import_splats(path, blender_splats=kind == "blender"))
    rows["import"] = (wall, cpu)
    scene = scene_for_f12(bpy, work)
    bpy.context.view_layer.update()
    ext("blender.render.compositor_bridge").ensure_bridge(scene)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    gather.clear_cache()
    rows["gather"] = timed(lambda: gather.gather(depsgraph))[:2]
    rows["gather, cached"] = timed(lambda: gather.gather(depsgraph))[:2]
    bpy.ops.render.render(write_still=True)  # warm
    rows["F12 (Cycles 1 sample, 320x240)"] = timed(lambda: bpy.ops.render.render(write_still=True))[:2]

    transform = geometry_nodes(bpy, obj)
    bpy.context.view_layer.update()

    def evaluate():
        transform.inputs["Translation"].default_value[0] += 0.1
        bpy.context.view_layer.update()
        return gather.gather(bpy.context.evaluated_depsgraph_get())

    rows["geometry nodes + gather"] = timed(evaluate)[:2]
    obj.modifiers.clear()
    bpy.context.view_layer.update()

    for other in bpy.context.view_layer.objects:
        other.select_set(other == obj)
    bpy.context.view_layer.objects.active = obj
    rows["crop half (splat.crop)"] = timed(lambda: bpy.ops.splat.crop(
        shape="BOX", center=(-50, 0, 0), size=(100, 100, 100)))[:2]
    count = lambda: len(obj.data.points) if kind == "blender" else len(obj.data.vertices)  # noqa: E731
    before = count()
    wall, cpu, result = timed(lambda: bpy.ops.object.mode_set(mode="EDIT"))
    rows["edit mode enter"] = (wall, cpu)
    print(f"  {kind}: mode_set EDIT {result}, mode {bpy.context.mode}, {before} points")
    if kind == "blender":
        select = lambda: bpy.ops.pointcloud.select_all(action="SELECT")  # noqa: E731
        delete = lambda: bpy.ops.pointcloud.delete()  # noqa: E731
    else:
        select = lambda: bpy.ops.mesh.select_all(action="SELECT")  # noqa: E731
        delete = lambda: bpy.ops.mesh.delete(type="VERT")  # noqa: E731
    try:
        wall, cpu, result = timed(select)
        rows["edit: select all"] = (wall, cpu)
        print(f"  {kind}: select all {result}")
        wall, cpu, result = timed(delete)
        rows["edit: delete selected"] = (wall, cpu)
        print(f"  {kind}: delete {result}")
    except (AttributeError, RuntimeError) as error:
        print(f"  {kind}: edit-mode operators failed: {error}")
    rows["edit mode leave"] = timed(lambda: bpy.ops.object.mode_set(mode="OBJECT"))[:2]
    print(f"  {kind}: {count()} points left after Edit Mode delete")
    del np
    return rows


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--n", type=int, default=1_000_000)
    parser.add_argument("--degree", type=int, default=3)
    parser.add_argument("--work", type=Path, default=Path(tempfile.mkdtemp()))
    parser.add_argument("--zip", type=Path)
    args = parser.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    os.environ.setdefault("BLENDER_USER_RESOURCES", str(args.work / "user"))
    import bpy

    if args.zip is not None:
        bpy.ops.extensions.package_install_files(filepath=str(args.zip), repo="user_default",
                                                 enable_on_install=True)
    elif EXTENSION not in bpy.context.preferences.addons:
        bpy.ops.wm.read_userpref()
    path = args.work / f"bench_{args.n}.ply"
    ext("core.splat_io").save(random_gaussians(args.n, args.degree), path)
    results = {kind: bench(bpy, kind, path, args.work, args.n) for kind in ("addon", "blender")}
    print(f"\nbpy {bpy.app.version_string}, {args.n:,} Gaussians, SH {args.degree}; "
          f"seconds wall (CPU)")
    print(f"| {'step':28s} | {'add-on splat object':>22s} | {'Blender splat cloud':>22s} |")
    print(f"|{'-' * 30}|{'-' * 24}:|{'-' * 24}:|")
    for row in results["addon"]:
        cells = [f"{r[row][0]:8.3f} ({r[row][1]:7.3f})" if row in r else "-" for r in results.values()]
        print(f"| {row:28s} | {cells[0]:>22s} | {cells[1]:>22s} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
