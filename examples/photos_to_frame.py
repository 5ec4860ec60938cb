"""From photos to a final frame with the command-line verbs (the README walkthrough).

    .venv/bin/python examples/photos_to_frame.py [--work /tmp/walkthrough] [--docs docs]
        [--steps N] [--downscale D]

The same verbs as `python -m addon ...` or `blender -c gaussian_splatting ...`, run in this
process through `addon.cli.main`:

1. `import-colmap examples/demo_colmap --out scene.blend` (30 photos, cameras, points);
2. `train scene.blend --out trained.blend` (CPU training with the defaults: until done, the
   photos at their size; the splat object joins the scene);
3. a mesh (a glossy monkey) is added with bpy, as a user would in the UI;
4. `render final.blend --camera 008.jpg`: the held-out photo 008's camera, at its own size,
   splats only and then with the monkey (Cycles, the splats composed by depth), under the
   Standard view transform (splats look as trained).

With `--docs` the pictures the README shows are written there (PNG): the photo, the splats
rendered from its camera, and the final frame, and the training's numbers (steps, Gaussians,
held-out PSNR/SSIM, wall and CPU seconds, and `photo_psnr`: the splats from camera 008
against its photo) to `walkthrough.json` beside them; they are printed
either way. `--steps` and `--downscale` are only there to try other settings.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from addon import cli  # noqa: E402

CAMERA = "008.jpg"  # every 8th photo is held out of training: a view the splats never saw


def verb(*args: str) -> tuple[float, float]:
    """Run `python -m addon ARGS` here; returns its (wall, process CPU) seconds."""
    print(f"\n$ python -m addon {' '.join(args)}", flush=True)
    start, cpu = time.perf_counter(), time.process_time()
    if cli.main(list(args)) != 0:
        sys.exit(f"{args[0]} failed")
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    print(f"({wall:.1f} s, {cpu:.1f} s of CPU)", flush=True)
    return wall, cpu


def trained_numbers(trained: Path) -> dict:
    """What the train verb wrote on the splat object: steps, Gaussians, held-out PSNR/SSIM."""
    import bpy

    bpy.ops.wm.open_mainfile(filepath=str(trained))
    obj = next(o for o in bpy.data.objects if "splat_trained_steps" in o)
    return {"steps": int(obj["splat_trained_steps"]), "gaussians": len(obj.data.vertices),
            "heldout_psnr": round(float(obj.get("splat_heldout_psnr", float("nan"))), 2),
            "heldout_ssim": round(float(obj.get("splat_heldout_ssim", float("nan"))), 4)}


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


def photo_psnr(photo: Path, frame: Path) -> float:
    """PSNR (dB) of a rendered frame's RGB against the photo of its camera, both 8-bit."""
    import numpy as np

    from addon.core.images import files

    ours = files.read_pixels(frame)[..., :3].astype(np.float64)
    theirs = files.read_pixels(photo)[..., :3].astype(np.float64)
    return float(10 * np.log10(255.0 ** 2 / np.mean((ours - theirs) ** 2)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", default=None, help="a fixed count (default: until done)")
    parser.add_argument("--downscale", default=None, help="(default: the photos' size)")
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
        options = (["--steps", args.steps] if args.steps else []) + (
            ["--downscale", args.downscale] if args.downscale else [])
        wall, cpu = verb("train", str(work / "scene.blend"), "--out",
                         str(work / "trained.blend"), *options, "--checkpoint",
                         str(work / "checkpoint.npz"))
        numbers = trained_numbers(work / "trained.blend") | {
            "train_wall_seconds": round(wall, 1), "train_cpu_seconds": round(cpu, 1),
            "options": " ".join(options) or "the defaults",
            "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
        (work / "walkthrough.json").write_text(json.dumps(numbers, indent=1))
        print(f"\nwalkthrough numbers: {numbers}", flush=True)
    standard_view(work / "trained.blend", work / "splats.blend")
    verb("render", str(work / "splats.blend"), "--camera", CAMERA, "--engine", "SPLAT_GAUSSIANS",
         "--out", str(work / "splats_"))
    add_monkey(work / "trained.blend", work / "final.blend")
    verb("render", str(work / "final.blend"), "--camera", CAMERA, "--out", str(work / "final_"))

    if args.docs:
        from addon.core.images import files

        docs = Path(args.docs).resolve()
        docs.mkdir(parents=True, exist_ok=True)
        photo = files.read_pixels(ROOT / "examples" / "demo_colmap" / "images" / CAMERA)
        files.write_pixels(docs / "walkthrough_photo.png", photo)
        frame = Path(sorted(work.glob("splats_*.png"))[-1])
        shutil.copyfile(frame, docs / "walkthrough_splats.png")
        shutil.copyfile(sorted(work.glob("final_*.png"))[-1], docs / "walkthrough_final.png")
        if (work / "walkthrough.json").is_file():
            numbers = json.loads((work / "walkthrough.json").read_text())
            numbers["photo_psnr"] = round(photo_psnr(docs / "walkthrough_photo.png",
                                                     docs / "walkthrough_splats.png"), 2)
            (docs / "walkthrough.json").write_text(json.dumps(numbers, indent=1))
        for name in ("walkthrough_photo.png", "walkthrough_splats.png", "walkthrough_final.png"):
            print(f"{docs / name}: {(docs / name).stat().st_size / 1024:.0f} KB")


if __name__ == "__main__":
    main()
