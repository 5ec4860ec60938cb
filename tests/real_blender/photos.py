"""Inside a real Blender (the extension installed): File > Import > Photos or Video on the demo
photos, whose workspace `blender -c gaussian_splatting reconstruct` has just made (so only the
import runs here). Where this Blender cannot load pycolmap (a distribution's build), the
operator must be greyed out, with pycolmap named as the reason. Prints one line:
`photos: imported N cameras` or `photos: greyed out: REASON`; exits non-zero otherwise.

    blender -b --python photos.py -- PHOTOS_FOLDER WORKSPACE
"""

import sys

import bpy

photos, workspace = sys.argv[sys.argv.index("--") + 1:][:2]
if not bpy.ops.splat.import_photos.poll():
    from bl_ext.user_default.gaussian_splatting.blender import dependencies
    from bl_ext.user_default.gaussian_splatting.blender.io import reconstruct

    reason = dependencies.unavailable(reconstruct.MODULES, reconstruct.FEATURE) or ""
    print(f"photos: greyed out: {reason}")
    sys.exit(0 if "pycolmap" in reason else 1)
result = bpy.ops.splat.import_photos(filepath=photos + "/", output=workspace, threads=2)
cameras = [o for o in bpy.context.scene.objects if "colmap_image_name" in o]
print(f"photos: imported {len(cameras)} cameras ({result})")
sys.exit(0 if result == {"FINISHED"} and len(cameras) == 30 else 1)
