"""LLFF-style downscaled folders: photos renamed `image000.png`, ... in the sorted order of the
model's names (core only, no bpy)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from addon.core.colmap import ColmapError, read_colmap


def _llff_workspace(shared_data: Path, tmp_path: Path, drop: int = 0) -> Path:
    """cup's model with its images_4 photos renamed image000.jpg, ... (sorted order)."""
    root = tmp_path / "cup"
    (root / "sparse").mkdir(parents=True)
    shutil.copytree(shared_data / "cup" / "sparse" / "0", root / "sparse" / "0")
    folder = root / "images_4"
    folder.mkdir()
    photos = sorted((shared_data / "cup" / "images_4").iterdir())
    for k, photo in enumerate(photos[drop:]):
        shutil.copyfile(photo, folder / f"image{k:03d}{photo.suffix}")
    return root


def test_renamed_folder_is_matched_in_sorted_order_with_a_warning(shared_data, tmp_path):
    reference = read_colmap(shared_data / "cup", "images_4", align=False)
    assert reference.warnings == []
    scene = read_colmap(_llff_workspace(shared_data, tmp_path), "images_4", align=False)
    assert not scene.missing and len(scene.images) == len(reference.images)
    assert len(scene.warnings) == 1 and "sorted name order" in scene.warnings[0]
    for k, (im, ref) in enumerate(zip(scene.images, reference.images)):
        assert im.name == ref.name and im.path.name == f"image{k:03d}{ref.path.suffix}"
        assert im.path.read_bytes() == ref.path.read_bytes()
        assert (im.camera.fx, im.camera.fy, im.camera.cx, im.camera.cy, im.camera.width,
                im.camera.height) == (ref.camera.fx, ref.camera.fy, ref.camera.cx, ref.camera.cy,
                                      ref.camera.width, ref.camera.height)
        assert (im.camera.world_to_camera == ref.camera.world_to_camera).all()


def test_renamed_folder_with_another_count_is_refused_with_the_reason(shared_data, tmp_path):
    with pytest.raises(ColmapError, match="counts differ"):
        read_colmap(_llff_workspace(shared_data, tmp_path, drop=1), "images_4", align=False)
