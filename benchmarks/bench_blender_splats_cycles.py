"""Side by side: Blender 5.3's own splats in Cycles against the add-on, time and PSNR.

    .venv/bin/python benchmarks/bench_blender_splats_cycles.py [--splats FILE] [--size 640x480]
        [--samples 4 16 64] [--bpy 5.3.0] [--zip FILE] [--reference-size 64x48] [--eevee]
    blender -b --python benchmarks/bench_blender_splats_cycles.py -- --inside --out DIR [options]

The same .ply, the same camera (looking at the splats' bounding box, as the installed-extension
checks place it), 16-bit PNGs under the "Standard" view transform over a black world:

  Cycles N      Blender's own PLY importer (`bpy.ops.wm.ply_import`: a point cloud of type
                'GAUSSIAN_SPLAT'), F12 in Cycles on the CPU with N samples (no denoising, no
                adaptive sampling, Cycles' other defaults), the add-on switched off;
  EEVEE         the same object in EEVEE, where a GPU context exists; where the only OpenGL
                is software (Mesa's llvmpipe, as on a machine without a GPU) the row says so
                and is not run, unless --eevee asks for it;
  add-on F12    the add-on's importer (`splat.import_splats`, the object placed as Blender's),
                F12 with the add-on composing its splats (Cycles, 4 samples, nothing else in
                the scene), and the add-on's renderer call alone (`splats only`);
  add-on F12 of Blender's object   where the add-on composes Blender's own splat objects
                (Blender 5.3 support): F12 of the PLY importer's object with the add-on on.

PSNR (dB, RGB in [0, 1]) of each image against the add-on's exact render (its renderer's float
output over black for the same Gaussians and camera). That render is held against the float64
reference (tests/reference.py) here, by the driver, at --reference-size (the reference loops
over every Gaussian in Python: at 640x480 it would take an hour): its largest error (1/255) over
the pixels the reference does not mark ambiguous is printed under the table.

From the project venv (bpy 5.0 has no splats of its own) the script is a driver: it builds the
linux-x64 zip (or takes --zip), runs itself in official bpy --bpy (default 5.3.0, Python 3.13) in
../shared/real-blender's py313 root with a fresh user folder and only the zip installed
(scripts/py313_root.py; needs root), then checks the exact render against the reference. With
--inside (in Blender 5.3+ or its bpy) it renders and prints the table itself; the extension
must be installed there (or --zip names it: it is installed into the user folder).
Timings are wall-clock (perf_counter) and process CPU time (every thread), one render each.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# tests/real_blender/scene_kit.py (plain bpy): in the checkout, or staged beside this file
sys.path[:0] = [str(Path(__file__).resolve().parent), str(ROOT / "tests" / "real_blender")]
PLAYBOT = ROOT.parent / "shared" / "data" / "splats" / "playbot_125k_sh2.ply"
EXTENSION_NAME = "gaussian_splatting"


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--splats", default=str(PLAYBOT))
    parser.add_argument("--size", default="640x480")
    parser.add_argument("--samples", type=int, nargs="+", default=[4, 16, 64])
    parser.add_argument("--bpy", default="5.3.0", help="the bpy version the driver runs")
    parser.add_argument("--zip", help="the extension zip (default: build linux-x64)")
    parser.add_argument("--reference-size", default="64x48")
    parser.add_argument("--eevee", action="store_true",
                        help="render EEVEE also on software OpenGL (no GPU)")
    parser.add_argument("--inside", action="store_true", help="render here (Blender 5.3+)")
    parser.add_argument("--out", help="the folder for the images and results.json (default: "
                        "none kept; with --inside a new temporary folder)")
    return parser.parse_args(argv)


def size_of(text: str) -> tuple[int, int]:
    width, height = text.lower().split("x")
    return int(width), int(height)


# ================================================================ inside Blender 5.3 (bpy)

def extension_module(bpy) -> str | None:
    """The installed extension's module name (bl_ext.<repo>.gaussian_splatting), if any."""
    import addon_utils

    names = [*bpy.context.preferences.addons.keys(), *(m.__name__ for m in addon_utils.modules())]
    return next((n for n in names if n.split(".")[-1] == EXTENSION_NAME), None)


def set_extension(bpy, module: str, on: bool) -> None:
    enabled = module in bpy.context.preferences.addons
    if on and not enabled:
        bpy.ops.preferences.addon_enable(module=module)
    elif not on and enabled:
        bpy.ops.preferences.addon_disable(module=module)


def ext(module: str, name: str):
    import importlib

    return importlib.import_module(f"{module}.{name}")


def clear_scene(bpy) -> None:
    for collection in (bpy.data.objects, bpy.data.meshes, bpy.data.pointclouds,
                       bpy.data.materials, bpy.data.cameras, bpy.data.lights, bpy.data.images):
        for item in list(collection):
            if not item.name.startswith("."):  # the add-on's hidden compositor helper stays
                collection.remove(item)


def new_objects(bpy, run) -> list:
    """The objects `run` adds to the current scene."""
    before = set(bpy.data.objects)
    result = run()
    assert result == {"FINISHED"}, result
    shown = set(bpy.context.scene.objects)
    return [o for o in set(bpy.data.objects) - before if o in shown]


def build_scene(bpy, blender_obj, size: tuple[int, int]):
    """A camera looking along +Y at the splats' bounding box (tests/real_blender/scene_kit.py,
    as the installed-extension checks); black world; Standard view."""
    import scene_kit

    scene = bpy.context.scene
    scene_kit.camera_in_front(bpy, scene, *scene_kit.world_bounds(blender_obj)[2:])
    if scene.world is None:
        scene.world = bpy.data.worlds.new("World")
    scene.world.color = (0, 0, 0)
    if scene.world.node_tree is not None:
        for node in scene.world.node_tree.nodes:
            if node.type == "BACKGROUND":
                node.inputs["Color"].default_value = (0, 0, 0, 1)
    render = scene.render
    render.resolution_x, render.resolution_y = size
    render.resolution_percentage = 100
    render.film_transparent = False
    render.dither_intensity = 0.0
    view = scene.view_settings
    view.view_transform, view.look, view.exposure, view.gamma = "Standard", "None", 0.0, 1.0
    settings = render.image_settings
    if hasattr(settings, "media_type"):
        settings.media_type = "IMAGE"
    settings.file_format, settings.color_mode, settings.color_depth = "PNG", "RGB", "16"
    return scene


def use_cycles(scene, samples: int) -> None:
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_denoising = False
    scene.cycles.use_adaptive_sampling = False


def f12(bpy, scene, path: Path) -> dict:
    """One F12 into `path`; wall and process CPU seconds."""
    scene.render.filepath = str(path)
    wall, cpu = time.perf_counter(), time.process_time()
    assert bpy.ops.render.render(write_still=True) == {"FINISHED"}
    return {"wall_s": time.perf_counter() - wall, "cpu_s": time.process_time() - cpu,
            "png": str(path)}


def camera_params(bpy, scene) -> dict:
    cam = scene.camera
    r = scene.render
    return dict(matrix_world=[list(row) for row in cam.matrix_world], lens=cam.data.lens,
                sensor_width=cam.data.sensor_width, sensor_height=cam.data.sensor_height,
                sensor_fit=cam.data.sensor_fit, shift_x=cam.data.shift_x,
                shift_y=cam.data.shift_y, resolution_x=r.resolution_x,
                resolution_y=r.resolution_y, resolution_percentage=r.resolution_percentage,
                pixel_aspect_x=r.pixel_aspect_x, pixel_aspect_y=r.pixel_aspect_y)


def blender_world_positions(obj):
    import numpy as np

    attribute = obj.data.attributes["position"]
    positions = np.empty(len(attribute.data) * 3, np.float32)
    attribute.data.foreach_get("vector", positions)
    m = np.array(obj.matrix_world, np.float64)
    return positions.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]


def gathered(bpy, module: str, obj):
    """`obj`'s world-space Gaussians as the add-on renders them."""
    return ext(module, "blender.sources.gather").gather(bpy.context.evaluated_depsgraph_get(),
                                                objects=[obj], use_cache=False).gaussians


def gpu_context(bpy) -> tuple[bool, str]:
    """(a hardware GPU context exists, what the OpenGL renderer is or why there is none).
    bpy in the background starts without one; gpu.init() makes one where it can (on a machine
    without a GPU: Mesa's software OpenGL, llvmpipe)."""
    import gpu

    try:
        renderer = gpu.platform.renderer_get()
    except Exception:
        try:
            gpu.init()
            renderer = gpu.platform.renderer_get()
        except Exception as error:
            return False, f"no GPU context ({' '.join(str(error).split())[:100]})"
    software = any(name in renderer.lower() for name in ("llvmpipe", "softpipe", "swrast"))
    return not software, (f"no GPU: only software OpenGL ({renderer})" if software
                          else renderer)


def inside(args: argparse.Namespace) -> int:
    import bpy
    import numpy as np

    if bpy.app.version < (5, 3):
        raise SystemExit(f"Blender {bpy.app.version_string} has no splats of its own (5.3+)")
    out = Path(args.out or tempfile.mkdtemp(prefix="bench-blender-splats-"))
    out.mkdir(parents=True, exist_ok=True)
    size = size_of(args.size)
    if args.zip:  # installed, switched on only for the add-on's rows
        result = bpy.ops.extensions.package_install_files(
            filepath=str(Path(args.zip).resolve()), repo="user_default", enable_on_install=False)
        assert result == {"FINISHED"}, result
    module = extension_module(bpy)
    if module is None:
        raise SystemExit("the Gaussian Splatting extension is not installed (or pass --zip)")
    set_extension(bpy, module, False)
    clear_scene(bpy)
    rows = []

    # Blender's own: its PLY importer, Cycles with the add-on off.
    (blender_obj,) = new_objects(bpy, lambda: bpy.ops.wm.ply_import(filepath=args.splats))
    assert blender_obj.type == "POINTCLOUD" and blender_obj.data.type == "GAUSSIAN_SPLAT", \
        (blender_obj.type, getattr(blender_obj.data, "type", None))
    scene = build_scene(bpy, blender_obj, size)
    for samples in args.samples:
        use_cycles(scene, samples)
        rows.append(dict(name=f"Blender 5.3 Cycles (CPU), {samples} samples",
                         **f12(bpy, scene, out / f"cycles_{samples}.png")))
        print(f"  {rows[-1]['name']}: {rows[-1]['wall_s']:.1f} s", flush=True)
    has_gpu, opengl = gpu_context(bpy)
    if has_gpu or (args.eevee and not opengl.startswith("no GPU context")):
        scene.render.engine = "BLENDER_EEVEE"
        rows.append(dict(name=f"Blender 5.3 EEVEE ({opengl})",
                         **f12(bpy, scene, out / "eevee.png")))
    else:
        rows.append(dict(name="Blender 5.3 EEVEE", skipped=opengl + (
            "" if args.eevee else "; --eevee renders it there anyway")))

    # The add-on: its own object of the same file, placed as Blender's object.
    set_extension(bpy, module, True)
    (ours,) = new_objects(bpy, lambda: bpy.ops.splat.import_splats(
        filepath=args.splats, forward_axis="Y", up_axis="Z"))
    ours.matrix_world = blender_obj.matrix_world.copy()
    blender_obj.hide_render = True
    bpy.context.view_layer.update()
    gaussians = gathered(bpy, module, ours)
    theirs = blender_world_positions(blender_obj)
    placement = float(np.abs(gaussians.means - theirs).max()) if len(theirs) == len(
        gaussians.means) else float("inf")
    assert placement < 1e-4, f"the two objects' Gaussians lie apart (max {placement})"
    camera_module = ext(module, "core.cameras")
    camera = camera_module.camera_from_blender(
        camera_module.BlenderCameraParams(**camera_params(bpy, scene)))
    renderer = ext(module, "core.render.renderer")
    exact = renderer.render(gaussians, camera)  # warm
    times = []
    for _ in range(3):
        start = time.perf_counter()
        exact = renderer.render(gaussians, camera)
        times.append(time.perf_counter() - start)
    exact_rgb = np.clip(exact.rgb, 0, 1)
    np.save(out / "exact_rgb.npy", exact.rgb)
    np.savez(out / "splats.npz", means=gaussians.means, log_scales=gaussians.log_scales,
             quats=gaussians.quats, opacity_logits=gaussians.opacity_logits, sh=gaussians.sh)
    use_cycles(scene, 4)
    f12(bpy, scene, out / "addon_warm.png")  # the first F12 reads the splats (cached after)
    rows.append(dict(name="add-on F12 of its own object (Cycles, 4 samples)",
                     **f12(bpy, scene, out / "addon.png")))
    rows.append(dict(name="  of which the add-on's renderer (splats only)",
                     wall_s=sorted(times)[1], cpu_s=None, png=None))
    # Blender's object with the add-on on: composed by the add-on where it takes Blender's
    # splats (then Cycles does not path-trace them), else Cycles renders it as above.
    ours.hide_render, blender_obj.hide_render = True, False
    bpy.context.view_layer.update()
    try:
        takes_blender_splats, why = len(gathered(bpy, module, blender_obj)) > 0, ""
    except Exception as error:  # an add-on that cannot read them: the row says why
        takes_blender_splats, why = False, " ".join(str(error).split())[:120]
    if takes_blender_splats:
        f12(bpy, scene, out / "addon_blender_warm.png")
        rows.append(dict(name="add-on F12 of Blender's splat object (Cycles, 4 samples)",
                         **f12(bpy, scene, out / "addon_blender.png")))
    else:
        rows.append(dict(name="add-on F12 of Blender's splat object",
                         skipped=why or "this add-on does not compose Blender's own splats"))

    for row in rows:
        if row.get("png"):
            row["psnr_db"] = psnr(read_rgb(Path(row["png"])), exact_rgb)
    results = dict(
        date=datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        blender=bpy.app.version_string, python=platform.python_version(),
        machine=machine(), splats=Path(args.splats).name, count=len(gaussians),
        size=f"{size[0]}x{size[1]}", placement_error=placement, rows=rows,
        camera=camera_params(bpy, scene), opengl=opengl)
    (out / "results.json").write_text(json.dumps(results, indent=1))
    print(table(results))
    return 0


def read_rgb(path: Path):
    """A 16-bit PNG's RGB in [0, 1] (OpenImageIO: the extension bundles it)."""
    import numpy as np

    oiio = __import__("OpenImageIO")
    buf = oiio.ImageBuf(str(path))
    if buf.has_error:
        raise OSError(f"{path}: {buf.geterror()}")
    return np.asarray(buf.get_pixels(oiio.FLOAT), np.float64)[..., :3]


def psnr(image, exact) -> float:
    import numpy as np

    mse = float(np.mean((np.asarray(image, np.float64) - np.asarray(exact, np.float64)) ** 2))
    return float("inf") if mse == 0 else 10 * math.log10(1.0 / mse)


def machine() -> str:
    name = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                name = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{name}, {os.cpu_count()} cores"


def table(results: dict) -> str:
    head = (f"{results['splats']} ({results['count']:,} Gaussians), {results['size']}, "
            f"Blender {results['blender']}, {results['machine']}, {results['date']}")
    lines = [head, "",
             "| render | time (wall) | CPU time (all threads) | PSNR against the exact render |",
             "| --- | --- | --- | --- |"]
    for row in results["rows"]:
        if "skipped" in row:
            lines.append(f"| {row['name']} | not run: {row['skipped']} | | |")
            continue
        cpu = "" if row.get("cpu_s") is None else f"{row['cpu_s']:.2f} s"
        value = row.get("psnr_db")
        quality = "" if value is None else "exact" if value == float("inf") else f"{value:.1f} dB"
        lines.append(f"| {row['name']} | {row['wall_s'] * 1000:,.0f} ms | {cpu} | {quality} |")
    return "\n".join(lines)


# ====================================================================== the driver (venv)

def reference_check(out: Path, results: dict, size: tuple[int, int]) -> str:
    """The add-on's renderer (this checkout's) against tests/reference.py, float64, for the
    benchmark's Gaussians and camera at `size`."""
    import numpy as np

    sys.path.insert(0, str(ROOT))
    sys.path.insert(0, str(ROOT / "tests"))
    import reference
    from addon.core.cameras import BlenderCameraParams, camera_from_blender
    from addon.core.gaussians import Gaussians
    from addon.core.render.renderer import render

    with np.load(out / "splats.npz") as arrays:
        gaussians = Gaussians(**{k: arrays[k] for k in arrays.files})
    params = dict(results["camera"], matrix_world=np.array(results["camera"]["matrix_world"]),
                  resolution_x=size[0], resolution_y=size[1], resolution_percentage=100)
    camera = camera_from_blender(BlenderCameraParams(**params))
    start = time.perf_counter()
    expected = reference.render_scene(gaussians, camera)
    seconds = time.perf_counter() - start
    ours = render(gaussians, camera).rgb
    keep = ~expected["ambiguous"]
    error = float(np.abs(ours[keep] - expected["rgb"][keep]).max()) * 255
    return (f"The add-on's renderer against the float64 reference (tests/reference.py) at "
            f"{size[0]}x{size[1]}, same Gaussians and camera: max error {error:.2g}/255 over "
            f"{keep.mean():.1%} of the pixels (the rest ambiguous), PSNR "
            f"{psnr(ours[keep], expected['rgb'][keep]):.1f} dB; the reference took "
            f"{seconds:.0f} s.")


def driver(args: argparse.Namespace, argv: list[str]) -> int:
    sys.path.insert(0, str(ROOT / "scripts"))
    from py313_root import Py313Root

    where = Py313Root(args.bpy)
    stage = where.stage_dir("bench-blender-splats-")
    try:
        if args.zip:
            zip_path = Path(args.zip).resolve()
        else:
            subprocess.run([sys.executable, str(ROOT / "scripts" / "build_extension.py"),
                            "--platform", "linux-x64", "--python", "3.13", "--out",
                            str(stage / "dist")], check=True)
            (zip_path,) = (stage / "dist").glob("*.zip")
        shutil.copy2(__file__, stage)
        shutil.copy2(ROOT / "tests" / "real_blender" / "scene_kit.py", stage)
        shutil.copy2(zip_path, stage / "extension.zip")
        splats = Path(args.splats).resolve()
        shutil.copy2(splats, stage / splats.name)
        out, user = stage / "out", stage / "user"
        out.mkdir()
        forwarded = ["--size", args.size, "--samples", *map(str, args.samples),
                     "--reference-size", args.reference_size,
                     *(["--eevee"] if args.eevee else [])]
        command = where.command(
            [where.inside(stage / Path(__file__).name), *forwarded, "--inside",
             "--zip", where.inside(stage / "extension.zip"),
             "--splats", where.inside(stage / splats.name), "--out", where.inside(out)],
            cwd=stage, env={"BLENDER_USER_RESOURCES": where.inside(user)})
        done = subprocess.run(command)
        if done.returncode != 0:
            print(f"the benchmark failed in bpy {args.bpy} (exit {done.returncode}); files in "
                  f"{stage}", file=sys.stderr)
            return 1
        results = json.loads((out / "results.json").read_text())
        if args.out:  # the images and results.json, kept
            shutil.copytree(out, Path(args.out), dirs_exist_ok=True)
        print()
        print(reference_check(out, results, size_of(args.reference_size)))
        print(f"command: .venv/bin/python benchmarks/bench_blender_splats_cycles.py {' '.join(argv)}")
        return 0
    finally:
        if "done" in locals() and done.returncode == 0:
            shutil.rmtree(stage, ignore_errors=True)


def main() -> int:
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]
    args = parse_args(argv)
    return inside(args) if args.inside else driver(args, argv)


if __name__ == "__main__":
    sys.exit(main())
