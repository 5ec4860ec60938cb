"""Messages about missing modules that a user can act on, and operators greyed out with the
reason when a module they need cannot be had (`addon.blender.dependencies`)."""

from __future__ import annotations

import sys

import bpy_support as bs
from bpy_support import bpy  # the shared bpy import
import pytest

from addon.blender import dependencies
from addon.core.colmap import errors as colmap_errors

MANIFEST = """schema_version = "1.0.0"
wheels = [
  "./wheels/splatcore-0.1.0-cp311-abi3-manylinux_2_17_x86_64.whl",
  "./wheels/xatlas-0.0.11-cp311-cp311-manylinux_2_17_x86_64.whl",
  "./wheels/xatlas-0.0.11-cp313-cp313-manylinux_2_17_x86_64.whl",
  "./wheels/pycolmap-4.0.1-cp311-cp311-manylinux_2_28_x86_64.whl",
  "./wheels/pycolmap-4.0.1-cp314-cp314-manylinux_2_28_x86_64.whl",
]
"""


@pytest.fixture
def installed(tmp_path, monkeypatch):
    """As in the installed extension: a manifest listing its wheels; this Python is 3.14."""
    manifest = tmp_path / "blender_manifest.toml"
    manifest.write_text(MANIFEST)
    monkeypatch.setattr(dependencies, "MANIFEST", manifest)
    monkeypatch.setattr(dependencies, "python_version", lambda: "3.14")
    dependencies.forget()
    yield
    dependencies.forget()


def test_bundled_pythons_come_from_the_manifest(installed):
    assert dependencies.bundled_pythons("xatlas") == ["3.11", "3.13"]
    assert dependencies.bundled_pythons("pycolmap") == ["3.11", "3.14"]
    assert dependencies.bundled_pythons("OpenImageIO") == []


def test_no_install_advice_for_a_python_nothing_is_built_for(installed, monkeypatch):
    """Debian's Blender 5.2 (Python 3.14): no xatlas exists for it, so the message must not tell
    the user to install one; it says what the extension carries and what to use instead."""
    monkeypatch.setitem(sys.modules, "xatlas", None)
    with pytest.raises(dependencies.MissingModule) as caught:
        dependencies.require("xatlas", "Converting splats to a mesh (its UV atlas)")
    message = str(caught.value)
    print(message)
    assert "only for Python 3.11, 3.13" in message and "blender.org" in message
    assert "install xatlas" not in message.lower() and "3.14" in message
    assert message.count("xatlas") <= 4


def test_a_wheel_for_this_python_that_does_not_load_says_reinstall(installed, monkeypatch):
    monkeypatch.setitem(sys.modules, "pycolmap", None)
    monkeypatch.setattr(colmap_errors, "_shared_gflags_loaded", lambda: False)
    message = dependencies.unavailable("pycolmap", "Importing a COLMAP scene")
    assert message is not None and "reinstall the extension" in message


def test_pycolmap_refused_in_a_distribution_blender_says_one_thing(monkeypatch):
    """Debian's Blender links the system's gflags: pycolmap would close it. Where its wheel is
    there, COLMAP work runs in a child process of Blender's Python, so nothing is refused; where
    it is not, the message says so and what to use, and nothing about installing pycolmap."""
    import importlib.util

    monkeypatch.delitem(sys.modules, "pycolmap", raising=False)
    monkeypatch.setattr(colmap_errors, "_shared_gflags_loaded", lambda: True)
    dependencies.forget()
    try:
        dependencies.require("pycolmap", "Importing a COLMAP scene")  # out of process: fine
        assert "pycolmap" not in sys.modules  # and not imported here
        assert dependencies.unavailable("pycolmap", "Importing a COLMAP scene") is None
        dependencies.forget()
        find_spec = importlib.util.find_spec
        monkeypatch.setattr(importlib.util, "find_spec",
                            lambda name, *a: None if name == "pycolmap" else find_spec(name, *a))
        with pytest.raises(dependencies.MissingModule) as caught:
            dependencies.require("pycolmap", "Importing a COLMAP scene")
        message = str(caught.value)
        print(message)
        assert "blender.org" in message and "install" not in message.lower()
        assert dependencies.unavailable(("pycolmap", "OpenImageIO"),
                                        "Importing a COLMAP scene") == message
    finally:
        dependencies.forget()


def test_operators_that_cannot_work_are_greyed_out_with_the_reason(monkeypatch, rng):
    from addon.blender import splat_object
    from scenes import random_gaussians

    bs.reset_scene()
    obj = splat_object.create_splat_object(random_gaussians(rng, 50, 0), "Splats")
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.splat.convert_to_mesh.poll()
    monkeypatch.setitem(sys.modules, "xatlas", None)
    assert not bpy.ops.splat.convert_to_mesh.poll()
    with pytest.raises(RuntimeError) as caught:  # the poll message is the reason
        bpy.ops.splat.convert_to_mesh()
    assert "xatlas" in str(caught.value) and "cannot import" in str(caught.value)
    monkeypatch.setitem(sys.modules, "pycolmap", None)
    assert not bpy.ops.splat.import_colmap.poll()
    with pytest.raises(RuntimeError, match="pycolmap"):
        bpy.ops.splat.import_colmap(directory="/nonexistent")

    class Operator:
        message = None

        @classmethod
        def poll_message_set(cls, text):
            cls.message = text

    assert not dependencies.poll_unavailable(Operator, ("numpy", "xatlas"), "Meshing")
    assert Operator.message.startswith("Meshing needs the Python module 'xatlas'")
    assert dependencies.poll_unavailable(Operator, "numpy", "Anything")
