"""Each COLMAP camera's own output size and pixel aspect, applied when it renders (bpy), and
the sparse points kept out of final renders.

A synthetic model (pycolmap) mixes a landscape and a portrait PINHOLE camera with fx != fy and
an off-centre principal point. Each camera made the scene camera is rendered by a probe render
engine that records what Blender's pipeline sees (size, camera matrix, window matrix; see
tests/blender/test_cameras_blender.py); the model's points projected through that must land within
0.5 px of COLMAP's own projection (pycolmap). Marker cameras are checked the same way.
"""

from __future__ import annotations

import time

import bpy_support as bs
from bpy_support import bpy  # the shared bpy import
import numpy as np
import pytest

from addon.blender.io import colmap_import
from tests.colmap_helpers import synthetic_workspace

CAMERAS = [("PINHOLE", 80, 60, [70.0, 61.0, 41.5, 29.0]),   # landscape
           ("PINHOLE", 48, 72, [50.0, 58.5, 23.0, 37.5])]   # portrait
IMAGES = [(f"img{k:02d}.png", k % 2) for k in range(6)]


class _Probe(bpy.types.RenderEngine):
    """Records the render size and Blender's projection of the scene camera; draws nothing."""

    bl_idname = "SPLAT_TEST_OUTPUT_PROBE"
    bl_label = "Output probe (tests)"
    recorded: dict = {}

    def render(self, depsgraph):
        scene, width, height = depsgraph.scene, self.resolution_x, self.resolution_y
        camera = scene.camera
        _Probe.recorded = {
            "camera": camera.name, "size": (width, height),
            "model": np.array(self.camera_model_matrix(camera, use_spherical_stereo=False), np.float64),
            "winmat": np.array(camera.calc_matrix_camera(
                depsgraph, x=width, y=height, scale_x=scene.render.pixel_aspect_x,
                scale_y=scene.render.pixel_aspect_y), np.float64)}
        result = self.begin_result(0, 0, width, height)
        self.end_result(result)


@pytest.fixture()
def model(tmp_path, rng):
    bs.reset_scene()
    if not _Probe.is_registered:
        bpy.utils.register_class(_Probe)
    rec = synthetic_workspace(tmp_path / "mixed", CAMERAS, IMAGES, rng=rng, n_points=200)
    collection = colmap_import.import_colmap(tmp_path / "mixed", align=False)
    scene = bpy.context.scene
    scene.render.engine = _Probe.bl_idname
    yield rec, collection, scene
    bpy.utils.unregister_class(_Probe)


def _blender_pixels(recorded, xyz: np.ndarray) -> np.ndarray:
    width, height = recorded["size"]
    model = recorded["model"].copy()
    model[:3, :3] /= np.linalg.norm(model[:3, :3], axis=0)
    clip = recorded["winmat"] @ np.linalg.inv(model) @ np.c_[xyz, np.ones(len(xyz))].T
    ndc = clip[:2] / clip[3]
    return np.stack([(ndc[0] + 1) * width / 2, (1 - ndc[1]) * height / 2], axis=1)


def _colmap_pixels(rec, name: str) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    image = next(im for im in rec.images.values() if im.name == name)
    xyz = np.array([p.xyz for p in rec.points3D.values()])
    pose = image.cam_from_world().matrix()
    xc = xyz @ pose[:, :3].T + pose[:, 3]
    front = xc[:, 2] > 0.1
    return xyz[front], image.camera.img_from_cam(xc[front]), (image.camera.width,
                                                             image.camera.height)


def _render(scene) -> dict:
    _Probe.recorded = {}
    assert bpy.ops.render.render() == {"FINISHED"}
    return _Probe.recorded


def test_each_camera_renders_at_its_photos_size_and_lines_up(model):
    rec, collection, scene = model
    worst = 0.0
    for name, _ in IMAGES:
        scene.camera = collection.objects[name]  # no message bus headless: render_init applies
        recorded = _render(scene)
        xyz, expected, size = _colmap_pixels(rec, name)
        assert recorded["camera"] == name and recorded["size"] == size
        error = np.abs(_blender_pixels(recorded, xyz) - expected).max()
        worst = max(worst, error)
        assert error < 0.5, (name, error)
    print(f"worst reprojection difference {worst:.2e} px over {len(IMAGES)} cameras")


def test_marker_cameras_apply_on_frame_change_and_render(model):
    rec, collection, scene = model
    for frame, (name, _) in enumerate(IMAGES[:2], start=1):
        marker = scene.timeline_markers.new(name, frame=frame)
        marker.camera = collection.objects[name]
    for frame, (name, _) in [(2, IMAGES[1]), (1, IMAGES[0]), (2, IMAGES[1])]:
        scene.frame_set(frame)
        assert (scene.render.resolution_x, scene.render.resolution_y) == \
            tuple(CAMERAS[IMAGES[frame - 1][1]][1:3])
        recorded = _render(scene)
        xyz, expected, size = _colmap_pixels(rec, name)
        assert recorded["camera"] == name and recorded["size"] == size
        assert np.abs(_blender_pixels(recorded, xyz) - expected).max() < 0.5
    # a render started on a frame whose marker camera is not yet the scene camera
    scene.camera = collection.objects[IMAGES[0][0]]
    scene.frame_current = 2  # no frame change: Blender switches the camera inside the render
    assert _render(scene)["size"] == tuple(CAMERAS[1][1:3])


def test_the_switch_turns_it_off(model):
    rec, collection, scene = model
    scene.colmap_camera_output = False
    scene.render.resolution_x, scene.render.resolution_y = 100, 100
    scene.camera = collection.objects[IMAGES[1][0]]
    assert _render(scene)["size"] == (100, 100)
    scene.colmap_camera_output = True
    assert _render(scene)["size"] == tuple(CAMERAS[1][1:3])


def test_sparse_points_stay_out_of_final_renders(model, tmp_path):
    rec, collection, scene = model
    points = next(o for o in collection.objects if o.name.endswith("points"))
    assert points.hide_render and not points.hide_viewport and not points.hide_get()
    shown = colmap_import.import_colmap(tmp_path / "mixed", align=False, render_points=True)
    assert not next(o for o in shown.objects if o.name.endswith("points")).hide_render


def test_an_animation_across_sizes_says_which_frames_do_not_match(model, tmp_path, capfd):
    rec, collection, scene = model
    for frame, (name, _) in enumerate(IMAGES[:2], start=1):
        scene.timeline_markers.new(name, frame=frame).camera = collection.objects[name]
    scene.frame_start, scene.frame_end = 1, 2
    scene.render.filepath = str(tmp_path / "frame_")
    scene.frame_set(1)
    assert bpy.ops.render.render(animation=True) == {"FINISHED"}
    out = capfd.readouterr().out
    assert f"frame 2: camera {IMAGES[1][0]!r} recorded 48x72" in out
    assert "render its frames one by one" in out


def test_import_is_a_staged_job_that_talks_and_cancels_cleanly(tmp_path, rng, capfd,
                                                               monkeypatch):
    bs.reset_scene()
    synthetic_workspace(tmp_path / "ws", CAMERAS, IMAGES, rng=rng, n_points=50)
    before = bs.scene_state()
    # Esc while building (StagedJob.cancel closes the generator at its next poll)
    steps = colmap_import.import_steps(tmp_path / "ws", align=False)
    while (step := next(steps)) is None or step[0] != "building":
        time.sleep(0.001 if step is None else 0)  # None: the reader works on its thread
    assert bpy.data.collections  # half built
    steps.close()
    assert bs.scene_state() == before and not bpy.data.collections
    # Esc while reading: the worker thread stops at its next progress report
    stopped = []

    def slow_read(*args, progress, **kwargs):
        try:
            while True:
                progress(0.5, "undistorting")
        except colmap_import.colmap.ColmapError:
            stopped.append(True)
            raise

    monkeypatch.setattr(colmap_import.colmap, "read_colmap_anywhere", slow_read)
    steps = colmap_import.import_steps(tmp_path / "ws", align=False)
    for _ in range(1000):  # the worker reports within a few polls, however loaded the machine
        step = next(steps)
        if step == ("reading", 0.5):
            break
        if step is None:
            time.sleep(0.01)
    else:
        pytest.fail("the reader never reported")
    steps.close()
    assert stopped == [True] and bs.scene_state() == before
    monkeypatch.undo()
    # headless, the operator prints a line per stage
    assert bpy.ops.splat.import_colmap(directory=str(tmp_path / "ws")) == {"FINISHED"}
    out = capfd.readouterr().out
    assert "Importing COLMAP: reading" in out and "Importing COLMAP: building" in out


def test_a_single_frame_render_never_says_it_is_an_animation(model, capfd):
    """F12 renders one frame at the size it set up: the animation's message must not appear,
    whichever camera renders (a marker's, another photo's, or one of the user's own)."""
    rec, collection, scene = model
    for frame, (name, _) in enumerate(IMAGES[:2], start=1):
        scene.timeline_markers.new(name, frame=frame).camera = collection.objects[name]
    own = bpy.data.objects.new("Ortho", bpy.data.cameras.new("Ortho"))
    own.data.type = "ORTHO"
    scene.collection.objects.link(own)
    capfd.readouterr()
    for frame in (1, 2):
        for camera in (collection.objects[IMAGES[3][0]], own):
            scene.frame_set(frame)
            scene.camera = camera
            _render(scene)
    assert "an animation renders" not in capfd.readouterr().out
    # The handlers as Blender's UI called them (4.3, 5.2): a frame change on the frame the render
    # started on, the scene's output not what the camera recorded: still no message
    scene.frame_set(1)
    colmap_import._on_render_init(scene)
    scene.render.resolution_percentage = 50
    colmap_import._on_frame_change(scene)
    assert "an animation renders" not in capfd.readouterr().out
    scene.frame_current = 2  # an animation's next frame, its camera of another size: said
    colmap_import._on_frame_change(scene)
    colmap_import._on_render_end()
    assert f"frame 2: camera {IMAGES[1][0]!r} recorded 48x72" in capfd.readouterr().out
