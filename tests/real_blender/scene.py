"""Runs inside a real Blender with the extension installed: builds the test scene and saves it.

    blender -b --factory-startup --python scene.py -- SPLATS.npz OUT.blend

Random splats (from SPLATS.npz, written by `check.py make`) about the origin, a red cube in
front of them, a blue plane behind them, a camera 6 units away looking along +Y; Cycles on the
CPU with emission materials (the mesh colours do not depend on lighting); 64x48 pixels;
"Standard" view transform. The 3D view looks through the camera, in Solid shading.
"""

from __future__ import annotations

import os
import sys

import bpy
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # scene_kit, copied beside this
import scene_kit  # noqa: E402

ADDON = "bl_ext.user_default.gaussian_splatting"


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
    scene_kit.meshes_and_camera(bpy, scene)
    scene_kit.render_settings(scene, threads=2, frames=(1, 2))
    bpy.ops.object.select_all(action="DESELECT")
    bpy.ops.wm.save_as_mainfile(filepath=out)
    print(f"scene written: {out}")


if __name__ == "__main__":
    args = sys.argv[sys.argv.index("--") + 1:]
    main(*args)
