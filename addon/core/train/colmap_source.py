"""Training on a COLMAP scene imported into Blender, the Blender-free part: what the operator
gathers on the main thread (`ColmapSource`), the dataset, the trainer set-up (`TrainRequest`)
and where checkpoints go. `addon/blender/train/operator.py` fills these from the collection.

The camera takes one path: the training cameras are the scene's camera objects as they are now
(read by `addon.blender.camera_adapter.camera_of` at each camera's recorded COLMAP resolution
and handed over by image name), so the splats are trained in the Blender world and their object
keeps an identity transform. Only the photos come from disk: the model's (undistorted) photos,
matched to the cameras by `colmap_image_name` and the cameras scaled to their pixels. The points
to start from are the collection's points object as it is (world space), else the model's points
mapped by the collection's `colmap_transform` (where the import put them).
"""

from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from .. import colmap
from ..cameras import Camera
from .dataset import MAX_WIDTH, ColmapDataset, Points, with_cameras
from .trainer import Trainer, TrainConfig


@dataclass
class ColmapSource:
    """What training needs from a COLMAP collection, as plain values a worker thread can use."""

    name: str
    model_dir: str
    image_folder: str  # absolute image folder of the import, or the folder's name
    cache_dir: str | None  # the root the import's undistortion cache lives in
    transform: np.ndarray  # (4, 4) COLMAP frame -> Blender world at import (for the points)
    cameras: dict[str, Camera] = field(default_factory=dict)  # image name -> its camera object
    points: Points | None = None  # the points object in world space, if there is one

    def dataset(self, image_folder: str = "", *, downscale: float = 1.0, test_every: int = 8,
                max_width: int = MAX_WIDTH, preload_threads: int = 0,
                progress: Callable[[float, str], None] | None = None) -> ColmapDataset:
        """The training dataset in the Blender world (runs on the worker). `image_folder`
        overrides the import's (a name beside the model or an absolute path). Photos are decoded
        now on `preload_threads` threads (0: every core; -1: lazily, on first use).
        `progress(fraction, message)` may raise to cancel."""
        report = progress or (lambda fraction, message: None)
        scene = colmap.read_colmap_anywhere(self.model_dir, image_folder or self.image_folder,
                                   cache_dir=self.cache_dir, align=False,
                                   progress=lambda f, m: report(0.3 * f, m))
        scene = with_cameras(scene.transformed(self.transform), self.cameras, self.points)
        data = ColmapDataset(scene, downscale=downscale, test_every=test_every, max_width=max_width)
        if preload_threads >= 0:
            data.preload(preload_threads, lambda f, m: report(0.3 + 0.7 * f, m))
        report(1.0, f"{len(data)} photos ready")
        return data


def safe_name(name: str) -> str:
    return re.sub(r"[^\w.-]+", "_", name).strip("_") or "scene"


def default_checkpoint(name: str, model_dir: str, blend_path: str = "") -> Path:
    """`<blend>_splats/<name>.npz` beside a saved .blend, else in the user cache folder (keyed
    by the model folder, so two unsaved scenes of the same name do not share one)."""
    if blend_path:
        blend = Path(blend_path)
        return blend.parent / f"{blend.stem}_splats" / f"{safe_name(name)}.npz"
    key = hashlib.sha1(str(model_dir).encode()).hexdigest()[:8]
    return colmap.user_cache_dir().parent / "checkpoints" / f"{safe_name(name)}-{key}.npz"


@dataclass
class TrainRequest:
    """A checked training request: the Blender layer runs it as a `core.jobs.TrainingJob` on any
    thread (`make_trainer` is that job's set-up), so this module needs nothing of jobs."""

    source: ColmapSource
    config: TrainConfig
    checkpoint: Path
    resume: bool = False
    image_folder: str = ""
    downscale: float = 1.0
    test_every: int = 8
    checkpoint_every: int = 1000
    update_every: int = 200
    compact: bool = True
    max_width: int = MAX_WIDTH

    def make_trainer(self, loading: Callable[[float, str], None] | None = None) -> Trainer:
        """Load the photos and make (or resume) the trainer; `loading(fraction, message)`
        reports (a job's `loading`, which stops a cancelled job between batches of photos)."""
        threads = self.config.threads
        dataset = self.source.dataset(self.image_folder, downscale=self.downscale,
                                      test_every=self.test_every, max_width=self.max_width,
                                      preload_threads=threads, progress=loading)
        if not self.resume:
            return Trainer(dataset, self.config)
        trainer = Trainer.load_checkpoint(self.checkpoint, dataset)
        trainer.config.threads = threads
        trainer.config.max_gaussians = self.config.max_gaussians
        return trainer


def train_request(source: ColmapSource, checkpoint: Path, config: TrainConfig | None = None, *,
                  resume: bool = False, image_folder: str = "", downscale: float = 1.0,
                  test_every: int = 8, checkpoint_every: int = 1000, update_every: int = 200,
                  compact: bool = True, max_width: int = MAX_WIDTH) -> TrainRequest:
    """Check the inputs; raises ValueError / FileNotFoundError."""
    if resume and not Path(checkpoint).is_file():
        raise FileNotFoundError(f"no checkpoint to resume at {checkpoint}")
    if not downscale >= 1.0:
        raise ValueError(f"downscale must be at least 1, got {downscale}")
    if max_width < 0:
        raise ValueError(f"max_width must be >= 0 (0: no limit), got {max_width}")
    if not source.cameras:
        raise ValueError(f"{source.name!r} has no COLMAP camera objects left to train from")
    return TrainRequest(source, config or TrainConfig(), Path(checkpoint), resume, image_folder,
                        downscale, test_every, checkpoint_every, update_every, compact, max_width)
