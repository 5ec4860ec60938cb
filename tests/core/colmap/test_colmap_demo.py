"""The demo scene's COLMAP model (examples/demo_colmap, built by examples/make_colmap_demo.py)
against the truth it was rendered from (examples/demo_colmap/known_poses.json).

- The committed model holds the known cameras exactly (it was written from them).
- Its points re-project onto their SIFT observations without a systematic offset: the
  renderer's and COLMAP's pixel conventions agree.
- Structure from motion: pycolmap reconstructs the committed photos from scratch (features,
  exhaustive matching, incremental mapping; about 20 s on two cores) and its camera centres
  match the known ones, after a similarity alignment, within 1 % of the scene size.
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from addon.core import colmap
from tests.colmap_helpers import project

DEMO = Path(__file__).resolve().parents[3] / "examples" / "demo_colmap"


@pytest.fixture(scope="module")
def known() -> dict:
    return json.loads((DEMO / "known_poses.json").read_text())


def _make_colmap_demo():
    path = DEMO.parent / "make_colmap_demo.py"
    spec = importlib.util.spec_from_file_location("make_colmap_demo", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_demo_model_holds_the_known_cameras(known):
    scene = colmap.read_colmap(DEMO, "images")
    assert len(scene.images) == len(known["images"]) == 30 and not scene.missing
    to_blender = np.linalg.inv(np.array(known["colmap_from_blender"]))
    for im in scene.images:
        truth = known["images"][im.name]
        want = np.array(truth["camera_to_world"])[:3, 3]
        got = colmap.transform_points(im.camera.centre, to_blender)[0]
        assert np.linalg.norm(got - want) < 1e-6  # Blender keeps its matrices in float32
        cam = im.camera
        assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height) == pytest.approx(
            (truth["fx"], truth["fy"], truth["cx"], truth["cy"], truth["width"], truth["height"]),
            rel=1e-12)
    assert len(scene.points) > 1000
    assert (DEMO / "images").is_dir() and sum(
        f.stat().st_size for f in DEMO.rglob("*") if f.is_file()) < 4 * 2**20


def test_demo_observations_have_no_pixel_offset():
    scene = colmap.read_colmap(DEMO, "images")
    residuals = []
    for im in scene.images:
        rows = scene.points.positions_of(im.point3D_ids)
        residuals.append(project(im.camera, scene.points.xyz[rows]) - im.points2D)
    residuals = np.concatenate(residuals)
    mean = residuals.mean(axis=0)
    print(f"demo: mean re-projection error {np.linalg.norm(residuals, axis=1).mean():.3f} px, "
          f"mean residual vector ({mean[0]:+.3f}, {mean[1]:+.3f}) px")
    assert np.abs(mean).max() < 0.05  # a half-pixel convention slip would show as 0.5
    assert np.linalg.norm(residuals, axis=1).mean() < 0.5


def test_demo_sfm_matches_known_poses():
    """Runs pycolmap's whole SfM pipeline on the 30 committed photos (the slowest COLMAP
    test, about 20 s)."""
    result = _make_colmap_demo().sfm_check(DEMO)
    assert result["registered"] == result["total"] == 30
    assert result["max_error"] < 0.01
