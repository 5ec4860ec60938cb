"""From photos to a final frame with the command-line verbs (the README walkthrough).

    .venv/bin/python examples/photos_to_frame.py [--steps 3000] [--work /tmp/walkthrough]
        [--docs docs]

The same verbs as `python -m addon ...` or `blender -c gaussian_splatting ...`, run in this
process through `addon.cli.main`:

1. `import-colmap examples/demo_colmap --out scene.blend` (30 photos, cameras, points);
2. `train scene.blend --out trained.blend` (CPU training; the splat object joins the scene);
3. a mesh (a glossy monkey) is added with bpy, as a user would in the UI;
4. `render final.blend --camera 008.jpg`: the held-out photo 008's camera, at its own size,
   splats only and then with the monkey (Cycles, the splats composed by depth), under the
   Standard view transform (splats look as trained).

With `--docs` the pictures the README shows are written there (PNG): the photo, the splats
rendered from its camera, and the final frame.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from addon import cli  # noqa: E402

CAMERA = "008.jpg"  # every 8th photo is held out of training: a view the splats never saw


def verb(*args: str) -> None:
    print(f"\n$ python -m addon {' '.join(args)}", flush=True)
    start = time.perf_counter()
    if cli.main(list(args)) != 0:
        sys.exit(f"{args[0]} failed")
    print(f"({time.perf_counter() - start:.1f} s)", flush=True)


def standard_view(trained: Path, out: Path) -> None:
    """The trained scene under the Standard view transform: splats look as trained (docs/guide/
    blender.md, "Colour"); Blender's default (AgX) would wash them out."""
    import bpy

    bpy.ops.wm.open_mainfile(filepath=str(trained))
    bpy.context.scene.view_settings.view_transform = "Standard"
    bpy.ops.wm.save_as_mainfile(filepath=str(out))


def add_monkey(trained: Path, final: Path) -> None:
    import math

    import bpy
    import mathutils

    bpy.ops.wm.open_mainfile(filepath=str(trained))
    scene = bpy.context.scene
    # On the ground (z = 0 after alignment) between the scene's centre and the photo's camera,
    # a little to the camera's right, turned to face it.
    camera = bpy.data.objects[CAMERA]
    towards = mathutils.Vector((camera.location.x, camera.location.y, 0.0)).normalized()
    right = mathutils.Vector((towards.y, -towards.x, 0.0))
    location = 1.3 * towards - 0.55 * right + mathutils.Vector((0.0, 0.0, 0.35))
    bpy.ops.mesh.primitive_monkey_add(size=0.6, location=location)
    monkey = bpy.context.active_object
    monkey.rotation_euler = (0.0, 0.0, math.atan2(towards.y, towards.x) + math.pi / 2)
    bpy.ops.object.shade_smooth()
    material = bpy.data.materials.new("Monkey")
    if material.node_tree is None:
        material.use_nodes = True
    bsdf = material.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (0.8, 0.25, 0.05, 1.0)
    bsdf.inputs["Roughness"].default_value = 0.3
    monkey.data.materials.append(material)
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    sun.data.energy = 3.0
    sun.rotation_euler = (0.6, 0.2, 0.8)
    scene.collection.objects.link(sun)
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 16
    scene.cycles.use_denoising = False
    scene.view_settings.view_transform = "Standard"  # splats look as trained
    bpy.ops.wm.save_as_mainfile(filepath=str(final))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", default="3000")
    parser.add_argument("--downscale", default="1")
    parser.add_argument("--work", default="/tmp/walkthrough")
    parser.add_argument("--docs", default="", help="write the README's pictures here")
    parser.add_argument("--reuse", action="store_true",
                        help="keep the work folder's trained.blend (skip import and training)")
    args = parser.parse_args()
    work = Path(args.work).resolve()
    work.mkdir(parents=True, exist_ok=True)

    if not (args.reuse and (work / "trained.blend").is_file()):
        verb("import-colmap", str(ROOT / "examples" / "demo_colmap"), "--out",
             str(work / "scene.blend"))
        verb("train", str(work / "scene.blend"), "--out", str(work / "trained.blend"),
             "--steps", args.steps, "--downscale", args.downscale, "--checkpoint",
             str(work / "checkpoint.npz"))
    standard_view(work / "trained.blend", work / "splats.blend")
    verb("render", str(work / "splats.blend"), "--camera", CAMERA, "--engine", "SPLAT_GAUSSIANS",
         "--out", str(work / "splats_"))
    add_monkey(work / "trained.blend", work / "final.blend")
    verb("render", str(work / "final.blend"), "--camera", CAMERA, "--out", str(work / "final_"))

    if args.docs:
        from addon.core.images import files as image_io

        docs = Path(args.docs).resolve()
        docs.mkdir(parents=True, exist_ok=True)
        photo = image_io.read_pixels(ROOT / "examples" / "demo_colmap" / "images" / CAMERA)
        image_io.write_pixels(docs / "walkthrough_photo.png", photo)
        frame = Path(sorted(work.glob("splats_*.png"))[-1])
        shutil.copyfile(frame, docs / "walkthrough_splats.png")
        shutil.copyfile(sorted(work.glob("final_*.png"))[-1], docs / "walkthrough_final.png")
        for name in ("walkthrough_photo.png", "walkthrough_splats.png", "walkthrough_final.png"):
            print(f"{docs / name}: {(docs / name).stat().st_size / 1024:.0f} KB")


if __name__ == "__main__":
    main()
