"""`read_colmap_anywhere` (core/colmap/outside.py): where pycolmap must not load in this process
(a Linux distribution's Blender), the reading runs in a child process of the same Python and
hands back the same scene; its errors come back by name, and a progress that raises (cancel)
ends the child."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from addon.core import colmap
from addon.core.colmap import errors as colmap_errors
from addon.core.colmap import outside

DEMO = Path(__file__).resolve().parents[3] / "examples" / "demo_colmap"


def refuse(monkeypatch) -> None:
    """This process as in Debian's Blender: pycolmap refused here."""
    monkeypatch.setattr(colmap_errors, "pycolmap_refusal", lambda: "a distribution's Blender")
    monkeypatch.setattr(outside, "pycolmap_refusal", lambda: "a distribution's Blender")


@pytest.fixture
def refused(monkeypatch):
    refuse(monkeypatch)


def test_the_child_reads_the_same_scene(monkeypatch, tmp_path):
    here = colmap.read_colmap(DEMO, "images", align=True, cache_dir=tmp_path)
    refuse(monkeypatch)
    seen = []
    there = colmap.read_colmap_anywhere(DEMO, "images", align=True, cache_dir=tmp_path,
                                        progress=lambda f, m: seen.append((f, m)))
    assert [im.name for im in there.images] == [im.name for im in here.images]
    for a, b in zip(there.images, here.images):
        assert np.array_equal(a.camera.world_to_camera, b.camera.world_to_camera)
        assert (a.camera.fx, a.camera.width) == (b.camera.fx, b.camera.width)
        assert a.path == b.path
    assert np.array_equal(there.points.xyz, here.points.xyz)
    assert np.array_equal(there.world_from_colmap, here.world_from_colmap)
    assert seen and seen[-1][0] == pytest.approx(1.0)


def test_its_errors_come_back_by_name(refused, tmp_path):
    with pytest.raises(colmap.ColmapError, match="nowhere: no such folder"):
        colmap.read_colmap_anywhere(tmp_path / "nowhere")


def test_a_progress_that_raises_ends_the_child(refused, tmp_path):
    class Cancelled(Exception):
        pass

    def cancel(fraction, message):
        raise Cancelled()

    with pytest.raises(Cancelled):
        colmap.read_colmap_anywhere(DEMO, "images", cache_dir=tmp_path, progress=cancel)


def test_in_this_process_when_it_may(monkeypatch, tmp_path):
    monkeypatch.setattr(outside, "read_colmap_in_a_process",
                        lambda *a, **k: pytest.fail("went to a child process"))
    assert "pycolmap" in sys.modules or colmap_errors.pycolmap_refusal() is None
    assert len(colmap.read_colmap_anywhere(DEMO, "images", cache_dir=tmp_path).images) == 30


def test_a_package_named_otherwise_in_the_child_still_unpickles(monkeypatch, tmp_path):
    """Installed in Blender the add-on is `bl_ext.user_default.gaussian_splatting`, while the
    child imports it by its folder's name: the scene's classes must map back. Here the child
    runs a copy of the package named `gaussian_splatting` while this process knows `addon`."""
    import shutil

    from addon.core import child

    copy = tmp_path / "extensions" / "gaussian_splatting"
    shutil.copytree(child.PACKAGE, copy, ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(child, "PACKAGE", copy)
    refuse(monkeypatch)
    scene = colmap.read_colmap_anywhere(DEMO, "images", cache_dir=tmp_path / "cache")
    assert type(scene) is colmap.ColmapScene and len(scene.images) == 30
    assert type(scene.images[0].camera).__module__ == "addon.core.cameras"
