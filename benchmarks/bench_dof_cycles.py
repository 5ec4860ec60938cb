"""Depth of field of splats against Cycles' own: small emissive spheres rendered by Cycles with
the camera's depth of field, and splats in their place rendered by the add-on's thin-lens blur.

    .venv/bin/python benchmarks/bench_dof_cycles.py [--samples 256]

A 50 mm camera at f/1.0 focused at 4 m looks at five spheres (radius 4 cm) at 2 to 9 m; each is
replaced by an isotropic Gaussian of the same projected second moment (sigma = radius / 2: a
disc's per-axis variance is radius^2 / 4). Per sphere, on the film's alpha (coverage): the blur
radius (square root of the blob's second moment about its centre, per axis, in pixels) in Cycles
and in the splat render, each with the sharp (depth of field off) size taken out in quadrature,
and the splats' predicted circle of confusion radius. Numbers only; never a test.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

WIDTH, HEIGHT = 640, 480
RADIUS = 0.04
DEPTHS = [2.0, 3.0, 4.0, 6.0, 9.0]
FOCUS, FSTOP, LENS = 4.0, 1.0, 50.0


def build(bpy):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    cam.rotation_euler = (math.pi / 2, 0, 0)  # looks along +Y
    cam.data.lens = LENS
    cam.data.sensor_width = 36.0
    cam.data.dof.use_dof = True
    cam.data.dof.focus_distance = FOCUS
    cam.data.dof.aperture_fstop = FSTOP
    material = bpy.data.materials.new("Emit")
    if material.node_tree is None:
        material.use_nodes = True
    nodes = material.node_tree.nodes
    nodes.clear()
    emit = nodes.new("ShaderNodeEmission")
    out = nodes.new("ShaderNodeOutputMaterial")
    material.node_tree.links.new(emit.outputs[0], out.inputs["Surface"])
    centres = []
    for k, depth in enumerate(DEPTHS):
        x = (k - 2) * 0.13 * depth  # spread across the frame at every depth
        bpy.ops.mesh.primitive_uv_sphere_add(radius=RADIUS, location=(x, depth, 0.0),
                                             segments=48, ring_count=24)
        bpy.context.active_object.data.materials.append(material)
        centres.append((x, depth, 0.0))
    r = scene.render
    r.engine = "CYCLES"
    r.resolution_x, r.resolution_y, r.resolution_percentage = WIDTH, HEIGHT, 100
    r.film_transparent = True
    scene.cycles.device = "CPU"
    scene.cycles.use_denoising = False
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.max_bounces = 0
    return scene, cam, np.array(centres)


def cycles_alpha(bpy, scene, samples: int, dof: bool) -> np.ndarray:
    import OpenImageIO as oiio

    scene.camera.data.dof.use_dof = dof
    scene.cycles.samples = samples
    path = Path(tempfile.mkdtemp()) / "cycles.exr"
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    pixels = np.asarray(oiio.ImageBuf(str(path)).get_pixels(oiio.FLOAT))
    return pixels[..., 3]


def splat_alpha(camera, centres: np.ndarray) -> np.ndarray:
    from addon.core.gaussians import Gaussians
    from addon.core.render.renderer import render

    n = len(centres)
    g = Gaussians(centres.astype(np.float32), np.full((n, 3), np.log(RADIUS / 2), np.float32),
                  np.tile(np.float32([1, 0, 0, 0]), (n, 1)), np.full(n, 6.0, np.float32),
                  np.zeros((n, 1, 3), np.float32))
    return render(g, camera, antialiased=True).alpha


def blob_sizes(alpha: np.ndarray, camera, centres: np.ndarray, window: int = 40):
    """Per blob: (sum of alpha, sqrt of its second moment about its centroid, per axis)."""
    w2c = camera.world_to_camera
    p = centres @ w2c[:3, :3].T + w2c[:3, 3]
    out = []
    for (x, y, z) in p:
        u, v = camera.fx * x / z + camera.cx, camera.fy * y / z + camera.cy
        r0, r1 = int(max(v - window, 0)), int(min(v + window, alpha.shape[0]))
        c0, c1 = int(max(u - window, 0)), int(min(u + window, alpha.shape[1]))
        a = alpha[r0:r1, c0:c1].astype(np.float64)
        ys, xs = np.mgrid[r0:r1, c0:c1] + 0.5
        m = a.sum()
        cx, cy = (a * xs).sum() / m, (a * ys).sum() / m
        spread = math.sqrt(0.5 * ((a * (xs - cx) ** 2).sum() + (a * (ys - cy) ** 2).sum()) / m)
        out.append((m, spread, z))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=256)
    args = parser.parse_args()
    import bpy
    import dataclasses

    from addon.blender.camera_adapter import camera_of

    scene, cam_obj, centres = build(bpy)
    camera = camera_of(cam_obj, scene.render)
    sharp_camera = dataclasses.replace(camera, aperture=0.0)
    cycles_blur = blob_sizes(cycles_alpha(bpy, scene, args.samples, True), camera, centres)
    cycles_sharp = blob_sizes(cycles_alpha(bpy, scene, args.samples, False), camera, centres)
    splat_blur = blob_sizes(splat_alpha(camera, centres), camera, centres)
    splat_sharp = blob_sizes(splat_alpha(sharp_camera, centres), camera, centres)
    print(f"Depth of field, 50 mm f/{FSTOP} focused at {FOCUS} m, {WIDTH}x{HEIGHT}, Cycles "
          f"{args.samples} samples; blur = sqrt(spread^2 - sharp spread^2) per axis, pixels")
    header = ["depth m", "CoC radius px", "Cycles blur", "splat blur", "ratio",
              "Cycles mass kept", "splat mass kept"]
    print("  ".join(f"{h:>16}" for h in header))
    for k, depth in enumerate(DEPTHS):
        coc = camera.aperture * abs(1 / camera.focus - 1 / depth) * camera.fx
        cb = math.sqrt(max(cycles_blur[k][1] ** 2 - cycles_sharp[k][1] ** 2, 0.0))
        sb = math.sqrt(max(splat_blur[k][1] ** 2 - splat_sharp[k][1] ** 2, 0.0))
        row = [f"{depth:.0f}", f"{coc:.2f}", f"{cb:.2f}", f"{sb:.2f}",
               f"{sb / cb:.3f}" if cb > 0.05 else "-",
               f"{cycles_blur[k][0] / cycles_sharp[k][0]:.3f}",
               f"{splat_blur[k][0] / splat_sharp[k][0]:.3f}"]
        print("  ".join(f"{c:>16}" for c in row))


if __name__ == "__main__":
    main()
