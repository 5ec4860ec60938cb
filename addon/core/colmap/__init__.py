"""COLMAP scenes: reading (through pycolmap 4.x), undistortion to pinhole, alignment.

`read_colmap(path, image_folder="images", ...)` takes a model folder (cameras, images,
points3D as .bin or .txt; COLMAP 4's rigs and frames files too) or a workspace folder
(`sparse/0`, `sparse`, and the image folders beside it) and returns a `ColmapScene`:

- one `ColmapImage` per *registered* image, sorted by name (names keep their subfolders), each
  with a pinhole `Camera` (our OpenCV convention: COLMAP's `cam_from_world` is exactly
  `Camera.world_to_camera`, and COLMAP's pixel centres are at i + 0.5 like ours) sized for the
  chosen image folder, its observations of 3D points in that camera's pixels, and the path of
  the photo that matches the camera (`None` where the photo is missing);
- the sparse points (`ColmapPoints`: xyz, colour, error, track length);
- `missing`: the registered images whose photos are not usable, with the reason;
- `world_from_colmap`: the similarity from COLMAP's frame to the scene's (identity unless
  aligned), so anything can be mapped back.

Image folders. `images_2/4/8` hold downscaled photos, possibly only some of them. Each photo's
camera is scaled by its own size ratio (photo size / COLMAP camera size, per axis: exact under
the pixel-edge convention); a missing photo's camera is scaled by the folder's ratio (from the
photos that are there, else the folder name's `_N`). A photo whose size fits neither the
camera nor the camera turned by its EXIF orientation is reported as missing.

Distorted cameras (every COLMAP model other than SIMPLE_PINHOLE and PINHOLE) are undistorted
to pinhole with pycolmap: `undistort_camera` at COLMAP's resolution chooses the pinhole camera
(and its crop, no blank pixels), which is then scaled like any other camera; observations go
through pycolmap's `Camera.cam_from_img`, photos through the same mapping (bilinear, every bit
depth, see `images.files.remap_bilinear`; it agrees with pycolmap's `undistort_image`). Undistorted
photos (and upright copies of photos stored sideways with an EXIF orientation), with the
undistorted model (a COLMAP workspace of its own: `images/`, `sparse/0/`), are cached in
`cache_dir`, by default `<workspace>/splat_cache/` when that is writable, else a user cache
folder; the input is never written.

Alignment (`align=True` or `ColmapScene.aligned()`): rotate so that the scene stands upright
(Blender's +Z up), then centre and scale it; see `alignment`.

Bad input raises `ColmapError` (a `ValueError`) naming the file and the problem. Binary models
are checked structurally before pycolmap reads them: a corrupt count in a .bin file otherwise
makes pycolmap allocate gigabytes or loop for minutes. Cameras are checked (sides 1..65536,
finite parameters, positive focal lengths) before pycolmap sees them; image names must be UTF-8
and stay inside the image folder, and nothing is read or written outside the image and cache
folders, links included; points and observations with NaN or Inf are dropped and counted in
`ColmapScene.dropped`.

Blender-free: numpy, pycolmap and OpenImageIO only.

Where pycolmap cannot load in this process (a Linux distribution's Blender), `read_colmap_anywhere`
reads in a child process of the same Python (`outside`); Blender's import and training use it.

The package, one job per module: `model` finds the model and its photos and reads it; `checks`
holds what a model from a stranger must pass (sizes, parameters, names that stay inside their
folders, finite values); `undistort` maps distorted cameras to pinhole; `cache` holds the
undistorted copies; `alignment` the similarities; `scene` the data; `reader` puts them together. Everything public
is re-exported here (`from addon.core import colmap; colmap.read_colmap(...)`).
"""

from .alignment import (DEFAULT_SCENE_SIZE, alignment, camera_up_vectors, decompose_similarity,
                        estimate_up, ground_plane, look_at_centre, similarity, transform_camera,
                        transform_points)
from .cache import CACHE_VERSION, Progress, user_cache_dir
from .errors import ColmapError, import_pycolmap
from .model import (IMAGE_FOLDERS, MODEL_FILES, check_binary_model, find_image_dir, find_model,
                    read_reconstruction)
from .outside import read_colmap_anywhere
from .reader import read_colmap
from .scene import PINHOLE_MODELS, ColmapImage, ColmapPoints, ColmapScene
from .undistort import PinholeIntrinsics, pinhole_of, undistortion_map

__all__ = [
    "CACHE_VERSION", "DEFAULT_SCENE_SIZE", "IMAGE_FOLDERS", "MODEL_FILES", "PINHOLE_MODELS",
    "ColmapError", "ColmapImage", "ColmapPoints", "ColmapScene", "PinholeIntrinsics", "Progress",
    "alignment", "camera_up_vectors", "check_binary_model", "decompose_similarity", "estimate_up",
    "find_image_dir", "find_model", "ground_plane", "import_pycolmap", "look_at_centre",
    "pinhole_of", "read_colmap", "read_colmap_anywhere", "read_reconstruction", "similarity",
    "transform_camera", "transform_points", "undistortion_map", "user_cache_dir",
]
