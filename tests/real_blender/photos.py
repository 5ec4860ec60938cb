"""Inside a real Blender (the extension installed): File > Import > Photos or Video on the demo
photos, whose workspace `blender -c gaussian_splatting reconstruct` has just made (so only the
import runs here), then a short training on the scene. In a distribution's Blender (Debian's
5.2: pycolmap cannot load in its process) both read the model in a child process of its Python.
Prints one line, `photos: imported N cameras, trained M Gaussians (pycolmap in this process:
yes/no)`, and exits non-zero when anything is short or greyed out.

    blender -b --python photos.py -- PHOTOS_FOLDER WORKSPACE
"""

import sys
import tempfile

import bpy

photos, workspace = sys.argv[sys.argv.index("--") + 1:][:2]
if not bpy.ops.splat.import_photos.poll():
    print("photos: Import Photos or Video is greyed out")
    sys.exit(1)
result = bpy.ops.splat.import_photos(filepath=photos + "/", output=workspace, threads=2)
cameras = [o for o in bpy.context.scene.objects if "colmap_image_name" in o]
collection = next(c for c in bpy.data.collections if any(o in cameras for o in c.objects))
before = set(bpy.data.objects)
trained = bpy.ops.splat.train(collection=collection.name, steps=30, threads=2,
                              max_gaussians=5000, sh_degree=0, update_every=0,
                              checkpoint_every=0,
                              checkpoint=tempfile.mkdtemp() + "/train.npz")
made = [o for o in set(bpy.data.objects) - before if o.type == "MESH"]
count = len(made[0].data.vertices) if made else 0
print(f"photos: imported {len(cameras)} cameras, trained {count} Gaussians (pycolmap in this "
      f"process: {'yes' if 'pycolmap' in sys.modules else 'no'})")
sys.exit(0 if result == trained == {"FINISHED"} and len(cameras) == 30 and count > 0 else 1)
