"""Runs inside a real Blender: F12 of the open file, as `bpy.ops.render.render` does it.

    blender -b FILE.blend --python render_still.py -- OUT_PREFIX [--no-splats] [--multilayer]
                                                        [--camera KIND]

Writes OUT_PREFIX.png (or .exr with --multilayer); exits 1 if the render did not finish (an
exception or a result other than {'FINISHED'}): this is what a script or add-on calling F12
sees. --no-splats renders the meshes alone (Composite Splats off), as the reference.
--camera KIND makes the scene's camera one of scene_kit.CAMERA_KINDS first (ORTHO,
EQUIRECTANGULAR, FISHEYE_EQUISOLID).
"""

from __future__ import annotations

import os
import sys
import time

import bpy

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # scene_kit, copied beside this
import scene_kit  # noqa: E402


def main(prefix: str, *flags: str) -> int:
    scene = bpy.context.scene
    if "--camera" in flags:
        scene_kit.set_camera_kind(scene.camera.data, flags[flags.index("--camera") + 1])
    if "--no-splats" in flags:
        scene.splat_render.enabled = False
    if "--multilayer" in flags:
        settings = scene.render.image_settings
        scene_kit.multilayer_exr(settings)
        settings.exr_codec = "ZIP"
        scene.view_layers[0].use_pass_z = True
    scene.render.filepath = prefix
    start = time.perf_counter()
    try:
        result = bpy.ops.render.render(write_still=True)
    except Exception as error:  # noqa: BLE001 - what the caller sees is the point
        print(f"render_still: render raised: {error}", flush=True)
        return 1
    print(f"render_still: {result} in {time.perf_counter() - start:.2f} s", flush=True)
    return 0 if result == {"FINISHED"} else 1


if __name__ == "__main__":
    code = main(*sys.argv[sys.argv.index("--") + 1:])
    sys.stdout.flush()
    import os
    os._exit(code)
