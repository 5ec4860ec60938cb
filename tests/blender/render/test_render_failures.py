"""Failures are loud (bpy): a render that cannot compose its splats fails, and every operator
that needs an optional module says so before doing any work.

Each failure is forced: a module that cannot be imported (`sys.modules[name] = None`), splats
that cannot be gathered, a native error while composing. The real-Blender script
(scripts/test_real_blender.sh) checks the same failures through `blender -b -a` exit codes.
"""

from __future__ import annotations

import sys

import bpy_support as bs
from bpy_support import bpy  # the shared bpy import
import numpy as np
import pytest

from addon.blender import dependencies, mesh_convert, splat_object
from addon.blender.render import failures, hooks
from scenes import random_gaussians


def _scene(rng, tmp_path):
    scene = bs.splats_and_cube_still(random_gaussians(rng, 200, 1, radius=1.0))
    scene.render.filepath = str(tmp_path / "frame")
    return scene


def _render_fails(scene, tmp_path, match: str) -> None:
    """F12 with write_still must raise or return CANCELLED, write nothing and say why."""
    camera = scene.camera
    try:
        result = bpy.ops.render.render(write_still=True)
    except RuntimeError:
        result = {"CANCELLED"}
    errors = failures.last_errors()
    written = sorted(p.name for p in tmp_path.glob("frame*"))
    assert written == [], f"a failed render left {written}"
    assert any(match in e for e in errors), errors
    # A failure that stopped the render before the meshes (a missing module) cancels it;
    # one found later (no Blender break handler in the bpy module) leaves no file behind.
    if "splatcore" in match:
        assert result == {"CANCELLED"}
    assert scene.camera == camera  # the camera the failure took is back


@pytest.fixture
def no_module(monkeypatch):
    """Make `import <name>` fail, as in a Blender without that module."""
    def hide(name: str) -> None:
        monkeypatch.setitem(sys.modules, name, None)
    return hide


def test_missing_native_module_fails_the_render(rng, tmp_path, no_module):
    scene = _scene(rng, tmp_path)
    no_module("splatcore")
    _render_fails(scene, tmp_path, "splatcore")


def test_splats_that_cannot_be_gathered_fail_the_render(rng, tmp_path, monkeypatch):
    scene = _scene(rng, tmp_path)

    def broken(*args, **kwargs):
        raise ValueError("forced: a bad splat object")
    monkeypatch.setattr(hooks, "capture_frame", broken)
    _render_fails(scene, tmp_path, "a bad splat object")


def test_a_native_error_fails_the_render(rng, tmp_path, monkeypatch):
    scene = _scene(rng, tmp_path)

    def broken(*args, **kwargs):
        raise RuntimeError("forced: the native compositor failed")
    monkeypatch.setattr(hooks, "compose", broken)
    _render_fails(scene, tmp_path, "the native compositor failed")


def test_splat_passes_without_openimageio_fail_before_rendering(rng, tmp_path, no_module):
    scene = _scene(rng, tmp_path)
    scene.render.image_settings.media_type = "MULTI_LAYER_IMAGE"
    no_module("OpenImageIO")
    try:
        bpy.ops.render.render(write_still=True)
    except RuntimeError:
        pass
    assert not list(tmp_path.glob("frame*"))
    assert any("Splat Passes" in e and "OpenImageIO" in e for e in failures.last_errors())
    # Turning the passes off renders the multilayer file without them.
    scene.splat_render.splat_passes = False
    assert bpy.ops.render.render(write_still=True) == {"FINISHED"}
    assert failures.last_errors() == []
    assert (tmp_path / "frame.exr").exists()


def test_a_render_after_a_failure_works(rng, tmp_path, monkeypatch):
    scene = _scene(rng, tmp_path)
    monkeypatch.setitem(sys.modules, "splatcore", None)
    _render_fails(scene, tmp_path, "splatcore")
    monkeypatch.undo()
    assert bpy.ops.render.render(write_still=True) == {"FINISHED"}
    assert (tmp_path / "frame.png").exists() and failures.last_errors() == []


def test_require_names_the_feature_and_the_fix(no_module):
    no_module("xatlas")
    with pytest.raises(dependencies.MissingModule) as caught:
        dependencies.require("xatlas", "Converting splats to a mesh")
    message = str(caught.value)
    assert "Converting splats to a mesh" in message and "'xatlas'" in message
    assert "install" in message
    assert isinstance(caught.value, ImportError)
    assert not dependencies.available("xatlas") and dependencies.available("numpy")
    dependencies.require("numpy", "anything")  # present: nothing happens


def test_mesh_conversion_without_xatlas_reports_before_working(rng, no_module):
    bs.reset_scene()
    obj = splat_object.create_splat_object(random_gaussians(rng, 100, 0, radius=1.0), "Ball")
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    no_module("xatlas")
    before = bs.scene_state()
    with pytest.raises(RuntimeError, match="xatlas"):
        bpy.ops.splat.convert_to_mesh(resolution=16, max_triangles=100, texture_size=32)
    assert bs.scene_state() == before
    with pytest.raises(mesh_convert.ConversionError, match="xatlas"):
        mesh_convert.convert_to_mesh(obj, resolution=16)


def test_colmap_import_without_pycolmap_reports_before_working(tmp_path, no_module):
    bs.reset_scene()
    no_module("pycolmap")
    before = bs.scene_state()
    collections = len(bpy.data.collections)
    with pytest.raises(RuntimeError, match="pycolmap"):
        bpy.ops.splat.import_colmap(directory=str(tmp_path))
    assert bs.scene_state() == before and len(bpy.data.collections) == collections


def test_exr_reader_matches_openimageio(rng, tmp_path):
    """The NumPy reader F12 uses (no OpenImageIO in some Blenders) reads what Blender and
    OpenImageIO write: every compression Blender uses for the render (none, ZIP, ZIPS)."""
    import OpenImageIO as oiio

    from addon.core.images import exr_scanlines

    names = ("ViewLayer.Combined.A", "ViewLayer.Combined.B", "ViewLayer.Combined.G",
             "ViewLayer.Combined.R", "ViewLayer.Depth.Z")
    for compression in ("none", "zip", "zips"):
        for fmt in ("float", "half"):
            pixels = rng.random((37, 53, len(names))).astype(np.float32)
            pixels[0, 0, -1] = np.inf
            spec = oiio.ImageSpec(53, 37, len(names), fmt)
            spec.channelnames = names
            spec.attribute("compression", compression)
            path = str(tmp_path / f"{compression}-{fmt}.exr")
            out = oiio.ImageOutput.create(path)
            assert out.open(path, spec) and out.write_image(pixels) and out.close()
            got = exr_scanlines.read_channels(path)
            want = pixels.astype(np.float16).astype(np.float32) if fmt == "half" else pixels
            for i, name in enumerate(names):
                assert np.array_equal(got[name], want[..., i]), (compression, fmt, name)
            if compression == "none" and fmt == "float":
                # mapped, not read: the same channels; a pass is a read-only view of them
                from addon.core.images.exr_layers import find_pass
                mapped = exr_scanlines.read_channels(path, mapped=True)
                assert all(np.array_equal(mapped[name], got[name]) for name in names)
                rgba = find_pass(mapped, "ViewLayer", "Combined", "RGBA")
                assert not rgba.flags.writeable and not rgba.flags.owndata
                assert np.array_equal(rgba, pixels[..., [3, 2, 1, 0]])
    # Blender's own multilayer file (multi-part on 5.0) reads the same as OpenImageIO reads it.
    scene = _scene(rng, tmp_path)
    scene.render.image_settings.media_type = "MULTI_LAYER_IMAGE"
    scene.render.image_settings.exr_codec = "ZIP"
    scene.splat_render.enabled = False
    assert bpy.ops.render.render(write_still=True) == {"FINISHED"}
    from addon.core.images import exr_layers as exr
    want = exr.read_channels(tmp_path / "frame.exr")
    got = exr_scanlines.read_channels(tmp_path / "frame.exr")
    assert sorted(got) == sorted(want)
    for name in want:
        assert np.array_equal(got[name], want[name]), name
    with pytest.raises(ValueError, match="not an OpenEXR"):
        exr_scanlines.read_channels(__file__)
