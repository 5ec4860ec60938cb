"""Splats to meshes, speed against error: depth error, colour PSNR, triangles, texture, time.

    .venv/bin/python benchmarks/bench_mesh.py                         # demo scene only
    .venv/bin/python benchmarks/bench_mesh.py --cup /tmp/cup.ply      # plus a trained cup model
        (train one with: .venv/bin/python examples/train.py --colmap ../shared/data/cup
         --images images_4 --steps 1500 --max-gaussians 25000 --out /tmp/cup.ply)

For each setting (volume resolution, triangle budget, texture size) it runs the pipeline of
`bpy.ops.splat.convert_to_mesh` (native depth renders -> TSDF -> surface nets -> Blender's
Decimate -> xatlas -> texture bake) and measures, in held-out views (cameras not used for the
fusion: for the demo scene a second, offset Fibonacci sphere; for the cup the COLMAP test
images, every 8th):
  - depth error: mean |mesh depth - splat depth| over pixels where the splats are opaque
    (alpha >= 0.5) and the mesh is hit (exact numpy z-buffer of the decimated mesh), as a
    percentage of the splats' bounding-box diagonal; "miss %" = opaque splat pixels the mesh
    does not cover plus mesh pixels where the splats are transparent;
  - colour PSNR (dB) of the textured mesh rendered by Cycles (emission shader showing the
    texture, black world, Standard view transform, 8 samples) against the splat render, both
    display sRGB on black;
  - triangles, texture size and seconds per stage.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

SETTINGS = ((32, 2_000, 256), (64, 8_000, 512), (128, 30_000, 1024))


def cycles_render(bpy, vertices, faces, corner_uvs, texture, camera, folder: Path, tag: str):
    from addon.blender import mesh_convert
    from addon.core.cameras import camera_to_blender

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    mesh = mesh_convert._new_mesh("bench", vertices, faces, corner_uvs)
    obj = bpy.data.objects.new("bench", mesh)
    scene.collection.objects.link(obj)
    image = mesh_convert._image("bench_tex", texture)
    material = bpy.data.materials.new("bench")
    if bpy.app.version < (5, 0, 0):
        material.use_nodes = True
    nodes = material.node_tree.nodes
    for n in list(nodes):
        if n.type != "OUTPUT_MATERIAL":
            nodes.remove(n)
    out = next(n for n in nodes if n.type == "OUTPUT_MATERIAL")
    emit = nodes.new("ShaderNodeEmission")
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = image
    tex.extension = "EXTEND"
    material.node_tree.links.new(tex.outputs["Color"], emit.inputs["Color"])
    material.node_tree.links.new(emit.outputs["Emission"], out.inputs["Surface"])
    mesh.materials.append(material)
    params = camera_to_blender(camera)
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    scene.collection.objects.link(cam)
    cam.matrix_world = params.matrix_world.T.tolist()
    cam.data.lens, cam.data.sensor_width = params.lens, params.sensor_width
    cam.data.sensor_height, cam.data.sensor_fit = params.sensor_height, params.sensor_fit
    cam.data.shift_x, cam.data.shift_y = params.shift_x, params.shift_y
    cam.data.clip_start, cam.data.clip_end = 0.01, 1e4
    scene.camera = cam
    r = scene.render
    r.resolution_x, r.resolution_y = params.resolution_x, params.resolution_y
    r.resolution_percentage = params.resolution_percentage
    r.pixel_aspect_x, r.pixel_aspect_y = params.pixel_aspect_x, params.pixel_aspect_y
    r.engine = "CYCLES"
    scene.cycles.samples = 8
    scene.cycles.device = "CPU"
    scene.cycles.use_denoising = False
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    world = bpy.data.worlds.new("w")
    world.color = (0, 0, 0)
    scene.world = world
    if world.node_tree is not None:
        bg = world.node_tree.nodes.get("Background")
        if bg is not None:
            bg.inputs["Color"].default_value = (0, 0, 0, 1)
    r.image_settings.file_format = "PNG"
    r.image_settings.color_depth = "8"  # byte PNG: pixels read back as display sRGB
    r.filepath = str(folder / f"{tag}.png")
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(r.filepath)
    px = np.array(img.pixels[:], np.float32).reshape(img.size[1], img.size[0], img.channels)
    return px[::-1, :, :3]  # top row first, display sRGB


def psnr(a, b) -> float:
    mse = float(np.mean((np.clip(a, 0, 1) - np.clip(b, 0, 1)) ** 2))
    return 10 * np.log10(1.0 / max(mse, 1e-12))


def run_scene(bpy, name, gaussians, fusion_cameras, test_cameras, settings, folder):
    from addon.blender import mesh_convert
    from addon.core.mesh import surface, texture
    from addon.core.render.renderer import render

    bounds = surface.splat_bounds(gaussians)
    diag = float(np.linalg.norm(bounds[1] - bounds[0]))
    tests = [(c, *render(gaussians, c)) for c in test_cameras]
    rows = []
    for resolution, budget, tex in settings:
        t = {}
        t0 = time.perf_counter()
        views = surface.render_views(gaussians, fusion_cameras)
        t["render"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        volume = surface.fuse_tsdf([v.depth for v in views], [v.alpha for v in views],
                                   fusion_cameras, bounds, resolution)
        t["fuse"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        v, f = surface.extract_surface(volume)
        v, f = surface.largest_components(v, f)
        t["extract"] = time.perf_counter() - t0
        extracted = len(f)
        t0 = time.perf_counter()
        bpy.ops.wm.read_factory_settings(use_empty=True)
        v, f = mesh_convert._decimate(v, f, budget)
        t["decimate"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        uvs = texture.unwrap(v, f, tex)
        t["unwrap"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        baked = texture.project_texture(v, f, views, tex, tolerance=2 * volume.grid.voxel,
                                             corner_uvs=uvs)
        t["texture"] = time.perf_counter() - t0
        depth_err, miss, psnrs = [], [], []
        for k, (cam, rgb, alpha, depth) in enumerate(tests):
            md = surface.zbuffer_depth(v, f, cam)
            opaque = alpha >= 0.5
            both = opaque & np.isfinite(md) & np.isfinite(depth)
            depth_err.append(np.abs(md[both] - depth[both]).mean() / diag * 100)
            miss.append(((opaque & ~np.isfinite(md)) | (~opaque & np.isfinite(md)
                                                       & (alpha < 0.05))).mean() * 100)
            image = cycles_render(bpy, v, f, uvs, baked.image, cam, folder, f"{name}_{resolution}_{k}")
            psnrs.append(psnr(image, rgb))
        rows.append((name, resolution, extracted, len(f), tex, np.mean(depth_err), np.mean(miss),
                     np.mean(psnrs), t))
        print_row(rows[-1], flush=True)
    return rows


HEADER = (f"{'scene':<6} {'res':>4} {'extracted':>9} {'tris':>6} {'tex':>5} {'depth err %':>11} "
          f"{'miss %':>6} {'PSNR dB':>7} | {'render':>6} {'fuse':>5} {'extract':>7} "
          f"{'decim':>5} {'unwrap':>6} {'proj':>5} {'total s':>7}")


def print_row(row, flush=False):
    name, res, extracted, tris, tex, derr, miss, p, t = row
    print(f"{name:<6} {res:>4} {extracted:>9} {tris:>6} {tex:>5} {derr:>11.3f} {miss:>6.2f} "
          f"{p:>7.2f} | {t['render']:>6.2f} {t['fuse']:>5.2f} {t['extract']:>7.2f} "
          f"{t['decimate']:>5.2f} {t['unwrap']:>6.2f} {t['texture']:>5.2f} {sum(t.values()):>7.2f}",
          flush=flush)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--demo", default=str(ROOT / "examples" / "demo_scene.ply"))
    parser.add_argument("--cup", default="", help="a .ply trained on ../shared/data/cup")
    parser.add_argument("--colmap", default=str(ROOT.parent / "shared" / "data" / "cup"))
    parser.add_argument("--views", type=int, default=48)
    parser.add_argument("--view-size", type=int, default=160)
    parser.add_argument("--test-size", type=int, default=96)
    parser.add_argument("--settings", default="", help="res:tris:tex,... (default 32/64/128)")
    args = parser.parse_args()
    settings = SETTINGS
    if args.settings:
        settings = tuple(tuple(int(x) for x in s.split(":")) for s in args.settings.split(","))

    import bpy  # noqa: F401

    from addon.core import splat_io
    from addon.core.mesh import surface
    from addon.core.cameras import Camera

    folder = Path(tempfile.mkdtemp(prefix="bench_mesh_"))
    print(HEADER)
    rows = []
    g = splat_io.load(args.demo)
    bounds = surface.splat_bounds(g)
    centre = 0.5 * (bounds[0] + bounds[1])
    radius = surface.framing_radius(bounds, 50)
    fusion = surface.fibonacci_cameras(centre, radius, args.views, args.view_size,
                                       args.view_size, 50)
    held = surface.fibonacci_cameras(centre, radius * 0.9, 7, args.test_size, args.test_size, 55)
    held = [held[i] for i in (1, 2, 3)]  # upper hemisphere, offset from the fusion lattice
    rows += run_scene(bpy, "demo", g, fusion, held, settings, folder)
    if args.cup:
        from addon.core.colmap import read_colmap
        from addon.core.train.dataset import ColmapDataset

        scene = read_colmap(args.colmap, image_folder="images_4")
        dataset = ColmapDataset(scene)

        def scaled(c: Camera, size: int) -> Camera:
            s = size / max(c.width, c.height)
            return Camera(c.world_to_camera, c.fx * s, c.fy * s, c.cx * s, c.cy * s,
                          round(c.width * s), round(c.height * s))

        fusion = [scaled(dataset.cameras[i], args.view_size) for i in dataset.train_indices]
        held = [scaled(dataset.cameras[i], args.test_size) for i in dataset.test_indices][:3]
        rows += run_scene(bpy, "cup", splat_io.load(args.cup), fusion, held, settings, folder)
    print("\n(command: .venv/bin/python benchmarks/bench_mesh.py" +
          (f" --cup {args.cup}" if args.cup else "") + ")")


if __name__ == "__main__":
    main()
