"""Structure from motion: a folder of photos or a video file to a COLMAP workspace (`images/`,
`database.db`, `sparse/0/`) that Import COLMAP and training read as they are. Blender-free;
pycolmap (COLMAP 4) does SIFT, matching and mapping on the CPU, PyAV reads videos.

    from addon.core import sfm
    report = sfm.run("photos/", "scene/", sfm.Options(threads=2), on_step=print)
    print(report.summary())        # registered 30 of 30 photos ...

One job per module: `source` (which files of a folder are photos), `photos` (the workspace's
upright, bounded copies and their EXIF focal length), `video` (frames: the sharpest of each time
slice), `sharpness`, `pairs` (which photos to match: exhaustive, sequential, or retrieval by
visual words), `mapping` (COLMAP's mappers, the focal-length retry, why a photo was left out),
`pipeline` (the stages, cached and resumed; progress and ETA). Bad input raises
`ReconstructionError` naming the file or folder.
"""

from .errors import ReconstructionError
from .pipeline import STAGES, Options, Report, Step, reconstruct, run

__all__ = ["STAGES", "Options", "ReconstructionError", "Report", "Step", "reconstruct", "run"]
