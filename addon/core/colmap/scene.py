"""What `read_colmap` returns: the scene's images (pinhole cameras, observations, photos) and
sparse points, in the scene's frame, with the similarity back to COLMAP's."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..cameras import Camera
from .alignment import DEFAULT_SCENE_SIZE, alignment, transform_camera, transform_points

PINHOLE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE")


@dataclass
class ColmapImage:
    image_id: int
    name: str  # COLMAP's image name, with its subfolders ("a/b.jpg")
    camera_id: int
    camera: Camera  # pinhole, in the scene's frame, in the pixels of `path`
    path: Path | None  # photo whose stored pixels match `camera` (original, or the cache's
    #                    undistorted or upright copy); None where there is none
    source_path: Path | None  # where the original photo is (or would be)
    points2D: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (M, 2) pixels
    point3D_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # (M,)


@dataclass
class ColmapPoints:
    ids: np.ndarray  # (N,) int64, COLMAP point3D ids
    xyz: np.ndarray  # (N, 3) float64, in the scene's frame
    rgb: np.ndarray  # (N, 3) uint8, sRGB
    error: np.ndarray  # (N,) float64, mean reprojection error in COLMAP's pixels
    track_length: np.ndarray  # (N,) int32, number of observations

    def __len__(self) -> int:
        return len(self.ids)

    def positions_of(self, ids) -> np.ndarray:
        """Row of each point id in these arrays (-1 where absent). `ids` is sorted on read."""
        ids = np.asarray(ids, np.int64)
        if len(self.ids) == 0:
            return np.full(ids.shape, -1, np.int64)
        rows = np.clip(np.searchsorted(self.ids, ids), 0, len(self.ids) - 1)
        return np.where(self.ids[rows] == ids, rows, -1)


@dataclass
class ColmapScene:
    model_dir: Path
    image_dir: Path | None
    image_folder: str
    images: list[ColmapImage]  # registered images, sorted by name
    points: ColmapPoints
    missing: dict[str, str]  # image name -> why its photo is not usable
    camera_models: dict[int, str]  # COLMAP camera id -> its model name
    undistorted_dir: Path | None  # cache folder of the undistorted workspace, if any
    world_from_colmap: np.ndarray = field(default_factory=lambda: np.eye(4))
    alignment_info: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)  # seconds per step
    # What was left out as unusable (non-finite values), with counts: "points3D", "observations".
    dropped: dict[str, int] = field(default_factory=dict)

    @property
    def with_photos(self) -> list[ColmapImage]:
        return [im for im in self.images if im.path is not None]

    @property
    def undistorted(self) -> bool:
        return any(m not in PINHOLE_MODELS for m in self.camera_models.values())

    def image(self, name: str) -> ColmapImage:
        for im in self.images:
            if im.name == name:
                return im
        raise KeyError(name)

    def transformed(self, similarity: np.ndarray) -> "ColmapScene":
        """The scene mapped by a similarity `x' = s R x + t` (4x4), cameras and points."""
        sim = np.asarray(similarity, np.float64)
        images = [replace(im, camera=transform_camera(im.camera, sim)) for im in self.images]
        points = replace(self.points, xyz=transform_points(self.points.xyz, sim))
        return replace(self, images=images, points=points,
                       world_from_colmap=sim @ self.world_from_colmap)

    def aligned(self, up: str = "auto", scene_size: float = DEFAULT_SCENE_SIZE) -> "ColmapScene":
        """Upright (+Z), centred and scaled: see `alignment`. Composes with any earlier one."""
        sim, info = alignment([im.camera for im in self.images], self.points.xyz, up=up,
                              scene_size=scene_size)
        out = self.transformed(sim)
        out.alignment_info = info
        return out

    def to_colmap(self, xyz: np.ndarray) -> np.ndarray:
        """Points of the scene's frame back in COLMAP's frame."""
        return transform_points(xyz, np.linalg.inv(self.world_from_colmap))
