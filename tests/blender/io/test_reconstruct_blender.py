"""File > Import > Photos or Video (bpy): the demo photos reconstructed in a child process and
imported as a COLMAP scene; cancelled at every stage or given bad input, the scene stays as it
was and the report says why."""

from __future__ import annotations

import shutil
import sys
import time
from pathlib import Path

import bpy
import pytest

from addon.blender import dependencies
from addon.blender.io import reconstruct
from addon.core.jobs import StagedJob
from tests.bpy_support import reset_scene, scene_state

DEMO_PHOTOS = Path(__file__).resolve().parents[3] / "examples" / "demo_colmap" / "images"


@pytest.fixture(autouse=True)
def empty_scene():
    reset_scene()


def test_the_demo_photos_become_a_scene_of_cameras(tmp_path):
    result = bpy.ops.splat.import_photos(filepath=str(DEMO_PHOTOS) + "/", threads=2,
                                         output=str(tmp_path / "demo_scene"))
    assert result == {"FINISHED"}
    (collection,) = bpy.data.collections
    cameras = [o for o in collection.objects if "colmap_image_name" in o]
    assert len(cameras) == 30 and collection.name == "demo_scene"
    assert any(o.type == "POINTCLOUD" or o.type == "MESH" for o in collection.objects)
    assert bpy.context.scene.view_settings.view_transform == "Standard"
    assert (tmp_path / "demo_scene" / "sparse" / "0" / "images.bin").is_file()


def test_the_menu_entry_and_the_default_output(tmp_path):
    assert reconstruct.default_output(DEMO_PHOTOS) == DEMO_PHOTOS.parent / "images_scene"
    video = tmp_path / "walk.mp4"
    video.write_bytes(b"")
    assert reconstruct.default_output(video) == tmp_path / "walk_scene"
    draws = bpy.types.TOPBAR_MT_file_import._dyn_ui_initialize()
    assert any(getattr(draw, "__module__", "").endswith("io.reconstruct") for draw in draws)


def test_the_operators_defaults_are_the_pipelines():
    """The dialog's defaults are the verb's and the pipeline's (it defaulted to the global
    mapper, which folded the demo's ring 2 times in 12, while the verb used incremental)."""
    from addon.core.sfm.pipeline import Options

    properties = bpy.ops.splat.import_photos.get_rna_type().properties
    for name, value in vars(Options()).items():
        assert properties[name].default == value, name


def test_bad_input_is_reported_and_changes_nothing(tmp_path):
    photos = tmp_path / "one"
    photos.mkdir()
    shutil.copy(DEMO_PHOTOS / "000.jpg", photos)
    before = scene_state()
    with pytest.raises(RuntimeError, match="1 usable photo"):
        bpy.ops.splat.import_photos(filepath=str(photos) + "/", output=str(tmp_path / "out"))
    assert scene_state() == before and not bpy.data.collections


@pytest.mark.parametrize("stage", ["starting", "finding features", "matching", "importing"])
def test_cancelled_at_any_stage_leaves_the_scene_as_it_was(tmp_path, stage):
    photos = tmp_path / "photos"
    photos.mkdir()
    for i in range(12):
        shutil.copy(DEMO_PHOTOS / f"{i:03d}.jpg", photos)
    before = scene_state()
    steps = reconstruct.reconstruct_steps(photos, tmp_path / "out", {"threads": 2},
                                          {"scene": bpy.context.scene})
    job = StagedJob(steps, reconstruct.STAGES, weights=reconstruct.WEIGHTS).start()
    while not job.done and not job.progress().message.startswith(stage):
        job.poll(0.05)
        time.sleep(0.02)  # as the modal timer: the main thread is Blender's between polls
    assert not job.done, f"finished before reaching {stage!r}"
    job.cancel()
    job.join()
    assert job.progress().phase == "cancelled" and job.result is None
    assert scene_state() == before and not bpy.data.collections
    assert not list(tmp_path.glob("out/sparse/0/*.bin")) or stage == "importing"


def test_a_distribution_blender_reconstructs_imports_and_trains_out_of_process(tmp_path,
                                                                             monkeypatch):
    """As in Debian's Blender (the system's gflags loaded: pycolmap must not load here): the
    reconstruction, the COLMAP reading for the import and for training each run in a child
    process of this Python, and pycolmap is never imported in this one."""
    from addon.core.colmap import errors as colmap_errors

    monkeypatch.setattr(colmap_errors, "_shared_gflags_loaded", lambda: True)
    monkeypatch.delitem(sys.modules, "pycolmap", raising=False)
    dependencies.forget()
    try:
        assert bpy.ops.splat.import_photos.poll() and bpy.ops.splat.import_colmap.poll()
        photos = tmp_path / "photos"
        photos.mkdir()
        for i in range(12, 30):
            shutil.copy(DEMO_PHOTOS / f"{i:03d}.jpg", photos)
        # One shared camera: what is tested here is where the work runs, and an arc of 18 views
        # with a camera each places a varying few fewer (one run of the suite placed under 16).
        assert bpy.ops.splat.import_photos(filepath=str(photos) + "/", threads=2,
                                           cameras="shared", features="fast",
                                           output=str(tmp_path / "scene")) == {"FINISHED"}
        (collection,) = bpy.data.collections
        assert sum("colmap_image_name" in o for o in collection.objects) >= 16
        before = set(bpy.data.objects)
        assert bpy.ops.splat.train(collection=collection.name, steps=30, threads=2,
                                   max_gaussians=5000, sh_degree=0, update_every=0,
                                   checkpoint_every=0,
                                   checkpoint=str(tmp_path / "t.npz")) == {"FINISHED"}
        assert len(set(bpy.data.objects) - before) == 1
        assert "pycolmap" not in sys.modules
    finally:
        dependencies.forget()
