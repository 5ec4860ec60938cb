"""Photos to a scene on the demo capture (examples/demo_colmap/images, 30 renders whose exact
cameras are in known_poses.json): every photo placed, cameras within 0.5 degrees and 1 % of the
scene size, the workspace read by the COLMAP reader as it is, and a second run all cached."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from addon.core import colmap, sfm
from addon.core.sfm.compare import model_poses, pose_errors

DEMO = Path(__file__).resolve().parents[3] / "examples" / "demo_colmap"
OPENCV_FROM_BLENDER_CAMERA = np.diag([1.0, -1.0, -1.0])


def known_poses() -> dict:
    known = json.loads((DEMO / "known_poses.json").read_text())
    return {name: (np.array(v["camera_to_world"])[:3, :3] @ OPENCV_FROM_BLENDER_CAMERA,
                   np.array(v["camera_to_world"])[:3, 3]) for name, v in known["images"].items()}


@pytest.fixture(scope="module")
def demo_workspace(tmp_path_factory) -> tuple[Path, sfm.Report, list[sfm.Step]]:
    folder = tmp_path_factory.mktemp("demo") / "scene"
    steps: list[sfm.Step] = []
    report = sfm.run(DEMO / "images", folder, sfm.Options(threads=2), on_step=steps.append)
    return folder, report, steps


def test_every_demo_photo_is_placed_at_its_known_camera(demo_workspace):
    import pycolmap

    folder, report, _ = demo_workspace
    assert report.photos == 30 and len(report.registered) == 30 and not report.left_out
    assert report.matching == "exhaustive" and report.cameras == 30  # a camera per photo
    errors = pose_errors(pycolmap, model_poses(pycolmap.Reconstruction(str(folder / "sparse/0"))),
                         known_poses())
    print(errors.summary())
    assert len(errors.names) == 30
    assert errors.rotation_deg.max() <= 0.5
    assert errors.position.max() <= 0.01


def test_progress_covers_every_stage_in_order(demo_workspace):
    _, _, steps = demo_workspace
    stages = list(dict.fromkeys(s.stage for s in steps))
    assert stages == list(sfm.STAGES)
    fractions = [s.fraction for s in steps]
    assert fractions == sorted(fractions) and fractions[-1] == pytest.approx(1.0)
    assert all(s.line() for s in steps)


def test_the_workspace_is_a_colmap_scene(demo_workspace):
    folder, _, _ = demo_workspace
    scene = colmap.read_colmap(folder, "images", cache_dir=folder.parent / "cache")
    assert len(scene.images) == 30 and not scene.missing and len(scene.points) > 500


def test_a_second_run_takes_every_stage_from_the_first(demo_workspace):
    folder, first, _ = demo_workspace
    started = time.perf_counter()
    again = sfm.run(DEMO / "images", folder, sfm.Options(threads=2))
    assert again.cached == list(sfm.STAGES) and not again.seconds
    assert again.registered == first.registered
    assert time.perf_counter() - started < 5.0
