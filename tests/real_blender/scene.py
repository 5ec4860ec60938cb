"""Runs inside a real Blender with the extension installed: builds the test scene and saves it.

    blender -b --factory-startup --python scene.py -- SPLATS.npz OUT.blend

Random splats (from SPLATS.npz, written by `check.py make`) about the origin, a red cube in
front of them, a blue plane behind them, a camera 6 units away looking along +Y; Cycles on the
CPU with emission materials (the mesh colours do not depend on lighting); 64x48 pixels;
"Standard" view transform. The 3D view looks through the camera, in Solid shading.
"""

from __future__ import annotations

import math
import os
import sys

import bpy
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # scene_kit, copied beside this
import scene_kit  # noqa: E402

ADDON = "bl_ext.user_default.gaussian_splatting"


def emission(name: str, colour) -> bpy.types.Material:
    return scene_kit.material(bpy, name, colour)


def main(npz: str, out: str) -> None:
    import importlib
    addon = importlib.import_module(ADDON)
    gaussians_mod = importlib.import_module(ADDON + ".core.gaussians")
    splat_object = importlib.import_module(ADDON + ".blender.splat_object")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    if not hasattr(bpy.types.Scene, "splat_render"):
        addon.register()
    data = np.load(npz)
    g = gaussians_mod.Gaussians(data["means"], data["log_scales"], data["quats"],
                                data["opacity_logits"], data["sh"])
    scene = bpy.context.scene
    splat_object.create_splat_object(g, "Splats")
    bpy.ops.mesh.primitive_cube_add(size=0.9, location=(0.35, -2.5, 0.15))
    bpy.context.active_object.data.materials.append(emission("Cube", (0.9, 0.3, 0.1)))
    bpy.ops.mesh.primitive_plane_add(size=40, location=(0, 2.5, 0), rotation=(math.pi / 2, 0, 0))
    bpy.context.active_object.data.materials.append(emission("Plane", (0.1, 0.35, 0.8)))
    camera = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(camera)
    camera.location = (0.0, -6.0, 0.0)
    camera.rotation_euler = (math.pi / 2, 0, 0)
    camera.data.lens = 35
    scene.camera = camera
    scene.render.resolution_x, scene.render.resolution_y = 64, 48
    scene.render.resolution_percentage = 100
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 4
    scene.cycles.use_denoising = False
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.max_bounces = 0
    scene.render.threads_mode = "FIXED"
    scene.render.threads = 2
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.render.dither_intensity = 0.0  # written files are compared with computed ones
    scene.frame_start, scene.frame_end = 1, 2
    settings = scene.render.image_settings
    settings.file_format = "PNG"
    settings.color_mode = "RGBA"
    settings.color_depth = "8"
    bpy.ops.object.select_all(action="DESELECT")
    bpy.ops.wm.save_as_mainfile(filepath=out)
    print(f"scene written: {out}")


if __name__ == "__main__":
    args = sys.argv[sys.argv.index("--") + 1:]
    main(*args)
