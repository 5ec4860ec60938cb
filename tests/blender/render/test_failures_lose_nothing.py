"""A failure in the middle of a long operation leaves the scene and every file as they were
(issue 14, item 4): no half object, no partial file, no changed setting. Each test injects a
failure at a stage of import, export, mesh conversion, training or COLMAP import."""

from __future__ import annotations

import os
import types
from pathlib import Path

import bpy_support as bs
from bpy_support import bpy  # the shared bpy import
import numpy as np
import pytest

from addon.blender.io import operators
from addon.blender import mesh_convert, splat_object
from addon.core import splat_io
from addon.core import atomic
from scenes import random_gaussians


class Injected(RuntimeError):
    """The failure these tests inject."""


def _data_counts() -> tuple:
    return (len(bpy.data.objects), len(bpy.data.meshes), len(bpy.data.materials),
            len(bpy.data.images), len(bpy.data.collections), len(bpy.data.cameras))


def _settings(scene) -> tuple:
    return (scene.camera.name if scene.camera else None, scene.render.resolution_x,
            scene.render.resolution_y, scene.render.resolution_percentage, scene.frame_current,
            bpy.context.view_layer.objects.active.name if bpy.context.view_layer.objects.active
            else None)


@pytest.fixture
def scene():
    bs.reset_scene()
    obj = splat_object.create_splat_object(random_gaussians(np.random.default_rng(3), 40, 1), "existing")
    bpy.context.view_layer.objects.active = obj
    bs.add_camera()
    return bpy.context.scene


def _fails_on_call(k: int, real):
    """`real`, raising Injected on its k-th call (1-based)."""
    calls = []

    def wrapper(*args, **kwargs):
        calls.append(1)
        if len(calls) == k:
            raise Injected(f"injected failure at call {k}")
        return real(*args, **kwargs)
    return wrapper


@pytest.mark.parametrize("failing_file", [1, 2])
def test_import_failing_while_building_leaves_nothing(scene, tmp_path, monkeypatch, failing_file):
    paths = []
    for k in range(2):
        paths.append(tmp_path / f"g{k}.ply")
        splat_io.save(random_gaussians(np.random.default_rng(k), 30, 1), paths[-1])
    before, counts, settings = bs.scene_state(), _data_counts(), _settings(scene)
    monkeypatch.setattr(splat_object, "write_gaussians",
                        _fails_on_call(failing_file, splat_object.write_gaussians))
    with pytest.raises(RuntimeError, match="Cannot import.*injected"):
        bpy.ops.splat.import_splats(directory=str(tmp_path),
                                    files=[{"name": p.name} for p in paths])
    assert (bs.scene_state(), _data_counts(), _settings(scene)) == (before, counts, settings)
    # the script function too
    monkeypatch.setattr(splat_object, "write_gaussians", _fails_on_call(1, splat_object.write_gaussians))
    with pytest.raises(Injected):
        operators.import_splats(paths[0])
    assert (bs.scene_state(), _data_counts(), _settings(scene)) == (before, counts, settings)


@pytest.mark.parametrize("suffix", [".ply", ".splat", ".spz"])
@pytest.mark.parametrize("stage", ["write", "sync", "rename"])
def test_export_failing_at_each_stage_leaves_the_old_file(scene, tmp_path, monkeypatch, suffix, stage):
    target = tmp_path / f"out{suffix}"
    target.write_bytes(b"the user's previous export")
    real = os
    broken = types.SimpleNamespace(**{name: getattr(real, name) for name in dir(real)
                                      if not name.startswith("__")})
    if stage == "write":
        def failing_open(name, mode):
            f = open(name, mode)
            f.write = _fails_on_call(1, lambda data: len(data))
            return f
        monkeypatch.setattr(atomic, "open", failing_open, raising=False)  # shadows the builtin
    elif stage == "sync":
        broken.fsync = _fails_on_call(1, real.fsync)
    else:
        broken.replace = _fails_on_call(1, real.replace)
    monkeypatch.setattr(atomic, "os", broken)
    settings = _settings(scene)
    with pytest.raises(RuntimeError, match="injected"):
        bpy.ops.splat.export_splats(filepath=str(target))
    assert target.read_bytes() == b"the user's previous export"
    assert sorted(p.name for p in tmp_path.iterdir()) == [target.name]  # no temporary left
    assert _settings(scene) == settings


@pytest.mark.parametrize("stage", [1, 2, 4, 8, 16])
def test_mesh_conversion_failing_at_each_stage_leaves_nothing(scene, monkeypatch, stage):
    """The cancel check runs between the stages (gather, surface, decimation, views, texture,
    object); a failure raised there at the k-th check stands for a failure in that stage."""
    obj = bpy.context.view_layer.objects.active
    before, counts, settings = bs.scene_state(), _data_counts(), _settings(scene)
    cancel = _fails_on_call(stage, lambda: False)
    with pytest.raises(Injected):
        mesh_convert.convert_to_mesh(obj, resolution=24, max_triangles=600, texture_size=64,
                                     view_count=16, view_size=48, cancel=cancel)
    assert (bs.scene_state(), _data_counts(), _settings(scene)) == (before, counts, settings)


def test_colmap_import_failing_while_building_leaves_nothing(scene, monkeypatch):
    from addon.blender.io import colmap_import
    demo = Path(__file__).resolve().parents[3] / "examples" / "demo_colmap"
    before, counts, settings = bs.scene_state(), _data_counts(), _settings(scene)
    real_new = bpy.data.cameras.new
    calls = []

    class Cameras:  # bpy.data.cameras, failing on the 5th new camera
        def new(self, name):
            calls.append(name)
            if len(calls) == 5:
                raise Injected("injected failure at camera 5")
            return real_new(name)

        def __getattr__(self, name):
            return getattr(bpy.data.cameras, name)

    class Data:  # bpy.data with those cameras
        cameras = Cameras()

        def __getattr__(self, name):
            return getattr(bpy.data, name)

    class Bpy:
        data = Data()

        def __getattr__(self, name):
            return getattr(bpy, name)

    monkeypatch.setattr(colmap_import, "bpy", Bpy())
    with pytest.raises(Injected):
        colmap_import.import_colmap(demo, "images", backgrounds=True, copy_photos=False)
    assert (bs.scene_state(), _data_counts(), _settings(scene)) == (before, counts, settings)


def test_training_failing_mid_run_leaves_no_half_object_nor_checkpoint(tmp_path, monkeypatch):
    from addon.blender import job_runner
    from addon.blender.train import operator
    from addon.core.train import trainer as train
    demo = Path(__file__).resolve().parents[3] / "examples" / "demo_colmap"
    bs.reset_scene()
    assert bpy.ops.splat.import_colmap(directory=str(demo), image_folder="images", align=True,
                                       backgrounds=False) == {"FINISHED"}
    collection = next(c for c in bpy.data.collections if operator.is_colmap_collection(c))
    scene = bpy.context.scene
    before, counts, settings = bs.scene_state(), _data_counts(), _settings(scene)
    keys = set(collection.keys())
    monkeypatch.setattr(train.Trainer, "train_step", _fails_on_call(30, train.Trainer.train_step))
    checkpoint = tmp_path / "ck.npz"
    try:
        with pytest.raises(RuntimeError, match="injected"):
            bpy.ops.splat.train(collection=collection.name, checkpoint=str(checkpoint), steps=60,
                                max_gaussians=5000, sh_degree=0, downscale=8.0, threads=2,
                                update_every=10)
    finally:
        job_runner.stop_all()
    assert (bs.scene_state(), _data_counts(), _settings(scene)) == (before, counts, settings)
    assert set(collection.keys()) == keys
    assert not checkpoint.exists() and list(tmp_path.iterdir()) == []


def test_training_failing_on_a_trained_object_puts_its_splats_back(tmp_path, monkeypatch):
    from addon.blender import job_runner, splat_object
    from addon.blender.train import operator
    from addon.core.train import trainer as train
    demo = Path(__file__).resolve().parents[3] / "examples" / "demo_colmap"
    bs.reset_scene()
    assert bpy.ops.splat.import_colmap(directory=str(demo), image_folder="images", align=True,
                                       backgrounds=False) == {"FINISHED"}
    collection = next(c for c in bpy.data.collections if operator.is_colmap_collection(c))
    options = dict(collection=collection.name, max_gaussians=5000, sh_degree=0, downscale=8.0,
                   threads=2, update_every=5)
    assert bpy.ops.splat.train(checkpoint=str(tmp_path / "first.npz"), steps=10,
                               **options) == {"FINISHED"}
    obj = collection[operator.OBJECT_KEY]
    trained = splat_object.gaussians_from_data(obj.data, drop_hidden=False)
    steps = obj["splat_trained_steps"]
    monkeypatch.setattr(train.Trainer, "train_step", _fails_on_call(12, train.Trainer.train_step))
    try:
        with pytest.raises(RuntimeError, match="injected"):
            bpy.ops.splat.train(checkpoint=str(tmp_path / "second.npz"), steps=40, **options)
    finally:
        job_runner.stop_all()
    assert collection[operator.OBJECT_KEY] == obj
    assert bs.gaussians_equal(splat_object.gaussians_from_data(obj.data, drop_hidden=False), trained)
    assert obj["splat_trained_steps"] == steps


def _failing_render(monkeypatch, tmp_path):
    """A scene of splats and meshes whose splat composite fails during F12, writing to
    tmp/out.png where a previous render lies."""
    from addon.blender.render import hooks
    from test_render_with_meshes import build_scene

    scene, *_ = build_scene(np.random.default_rng(5), "BLENDER_WORKBENCH", n=100)
    settings = scene.render.image_settings
    settings.media_type, settings.file_format, settings.color_mode = "IMAGE", "PNG", "RGBA"
    scene.render.filepath = str(tmp_path / "out")
    bpy.ops.render.render()  # a first render sets the compositor bridge up (that stays, by design)
    (tmp_path / "out.png").write_bytes(b"the previous render")
    monkeypatch.setattr(hooks, "compose", _fails_on_call(1, hooks.compose))
    return scene


def _render_settings(scene) -> tuple:
    r = scene.render
    return (r.filepath, r.use_render_cache, r.resolution_x, r.resolution_y, r.film_transparent,
            r.image_settings.file_format, r.image_settings.color_mode, r.use_compositing,
            scene.view_settings.view_transform, scene.camera.name)


def test_failed_render_changes_no_setting(monkeypatch, tmp_path):
    scene = _failing_render(monkeypatch, tmp_path)
    before, objects = _render_settings(scene), bs.scene_state()
    try:
        bpy.ops.render.render(write_still=True)
    except RuntimeError:
        pass
    assert _render_settings(scene) == before and bs.scene_state() == objects
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.png"]  # no temporary left


def test_failed_render_keeps_the_previous_file(monkeypatch, tmp_path):
    scene = _failing_render(monkeypatch, tmp_path)
    try:
        bpy.ops.render.render(write_still=True)
    except RuntimeError:
        pass
    assert (tmp_path / "out.png").read_bytes() == b"the previous render"
    assert scene.render.filepath == str(tmp_path / "out")


def test_a_render_that_succeeds_replaces_the_previous_file_and_leaves_nothing_aside(monkeypatch, tmp_path):
    _failing_render(monkeypatch, tmp_path)
    monkeypatch.undo()  # the composite works again
    bpy.ops.render.render(write_still=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.png"]
    assert (tmp_path / "out.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
