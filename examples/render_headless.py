"""Render splats with a mesh, headless: a still and a short animation, the way a script or a
render farm does it.

    blender --background --python examples/render_headless.py -- [options]
    .venv/bin/python examples/render_headless.py [options]          # the bpy wheel

Options: --splats FILE (default: the demo scene), --engine CYCLES|BLENDER_EEVEE|BLENDER_WORKBENCH,
--size 640x360, --samples 16 (Cycles), --frames 12, --out DIR (default: out/),
--save FILE.blend (also save the scene, e.g. for `blender -b FILE.blend -a` on a farm).

It loads the splats, adds a glossy monkey orbiting through them (in front of and behind the
splats as it goes round) on a mesh pedestal, a sun and a camera, then renders
`headless_still.png` with `bpy.ops.render.render(write_still=True)` and
`headless_0001.png`... with `bpy.ops.render.render(animation=True)`. Nothing else is needed:
the add-on composes the splats into every render (see docs/guide/blender.md, "Rendering with meshes").

Inside Blender the installed extension is used when it is enabled; otherwise (and with the
bpy wheel) the add-on is registered from this repository.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def parse_args() -> argparse.Namespace:
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--splats", default=str(ROOT / "examples" / "demo_scene.ply"))
    parser.add_argument("--engine", default="CYCLES",
                        choices=["CYCLES", "BLENDER_EEVEE", "BLENDER_WORKBENCH"])
    parser.add_argument("--size", default="640x360")
    parser.add_argument("--samples", type=int, default=16)
    parser.add_argument("--frames", type=int, default=12)
    parser.add_argument("--out", default=str(ROOT / "out"))
    parser.add_argument("--save", default="")
    return parser.parse_args(argv)


def ensure_addon():
    import bpy

    if not hasattr(bpy.types, "SPLAT_OT_import_splats"):  # no enabled extension: this repo's
        sys.path.insert(0, str(ROOT))
        import addon

        addon.register()
    return bpy


def build_scene(bpy, args) -> None:
    # An empty scene (not factory settings: they would also switch off an enabled extension).
    for collection in (bpy.data.objects, bpy.data.meshes, bpy.data.materials, bpy.data.lights,
                       bpy.data.cameras):
        for item in list(collection):
            collection.remove(item)
    scene = bpy.context.scene
    bpy.ops.splat.import_splats(filepath=str(Path(args.splats).resolve()))

    bpy.ops.mesh.primitive_monkey_add(size=0.7, location=(1.8, 0.0, 0.9))
    monkey = bpy.context.active_object
    bpy.ops.object.shade_smooth()
    monkey.data.materials.append(material(bpy, "Monkey", (0.8, 0.25, 0.05), roughness=0.25))
    bpy.ops.mesh.primitive_cylinder_add(radius=0.5, depth=0.3, location=(0.0, -2.2, 0.15))
    bpy.context.active_object.data.materials.append(material(bpy, "Pedestal", (0.7, 0.7, 0.75)))

    # The monkey orbits the splat planet: it passes in front of and behind it.
    pivot = bpy.data.objects.new("Orbit", None)
    scene.collection.objects.link(pivot)
    pivot.location = (0.0, 0.0, 0.0)
    monkey.parent = pivot
    scene.frame_start, scene.frame_end = 1, max(1, args.frames)
    behind = math.atan2(6.0, -5.5)  # seen from the camera, straight behind the planet
    pivot.rotation_euler = (0.0, 0.0, behind)
    pivot.keyframe_insert("rotation_euler", frame=1)
    pivot.rotation_euler = (0.0, 0.0, behind + 1.8 * math.pi)
    pivot.keyframe_insert("rotation_euler", frame=max(2, args.frames))

    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    sun.data.energy = 3.0
    sun.rotation_euler = (0.7, 0.2, 0.6)
    scene.collection.objects.link(sun)

    target = bpy.data.objects.new("Target", None)
    target.location = (0.0, 0.0, 0.9)
    scene.collection.objects.link(target)
    camera = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    camera.location = (5.5, -6.0, 3.2)
    camera.data.lens = 35
    track = camera.constraints.new("TRACK_TO")
    track.target = target
    scene.collection.objects.link(camera)
    scene.camera = camera

    width, height = (int(v) for v in args.size.lower().split("x"))
    render = scene.render
    render.engine = args.engine
    render.resolution_x, render.resolution_y, render.resolution_percentage = width, height, 100
    if args.engine == "CYCLES":
        scene.cycles.device = "CPU"
        scene.cycles.samples = args.samples
        scene.cycles.use_denoising = False
    scene.view_settings.view_transform = "Standard"  # splats look as the reference renders them
    world = bpy.data.worlds.new("World")
    world.color = (0.05, 0.06, 0.08)
    scene.world = world


def material(bpy, name: str, colour, roughness: float = 0.6):
    mat = bpy.data.materials.new(name)
    mat.diffuse_color = (*colour, 1.0)
    if mat.node_tree is None:
        mat.use_nodes = True
    bsdf = mat.node_tree.nodes.get("Principled BSDF")
    if bsdf is not None:
        bsdf.inputs["Base Color"].default_value = (*colour, 1.0)
        bsdf.inputs["Roughness"].default_value = roughness
    return mat


def main() -> None:
    args = parse_args()
    bpy = ensure_addon()
    from importlib import import_module

    build_scene(bpy, args)
    scene = bpy.context.scene
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    hooks = import_module(bpy.types.SPLAT_OT_import_splats.__module__.split(".blender.")[0]
                          + ".blender.render.hooks")

    scene.render.image_settings.file_format = "PNG"
    scene.render.filepath = str(out / "headless_still")
    start = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    print(f"still: {time.perf_counter() - start:.2f} s -> {out / 'headless_still.png'} "
          f"(splats: {hooks.last_stats.get('total_ms', 0):.0f} ms)")

    scene.render.filepath = str(out / "headless_")
    start = time.perf_counter()
    bpy.ops.render.render(animation=True)
    print(f"animation: {scene.frame_end - scene.frame_start + 1} frames in "
          f"{time.perf_counter() - start:.2f} s -> {out / 'headless_####.png'}")
    if args.save:
        bpy.ops.wm.save_as_mainfile(filepath=str(Path(args.save).resolve()))
        print(f"saved {args.save}: render it with `blender -b {args.save} -a`")


if __name__ == "__main__":
    main()
