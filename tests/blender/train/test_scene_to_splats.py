"""A Blender scene to splats ("Bake to Splats"): the Blender-free parts (cameras on a sphere,
surface sampling, the in-memory dataset, the colour conversion of the targets) and
`bpy.ops.splat.bake_to_splats` on a small coloured cube (8 views at 48x36, 100 steps): a splat
object and a readable .ply around the cube, every scene setting put back."""

from __future__ import annotations


import bpy
import numpy as np
import pytest

import time
from types import SimpleNamespace

from addon.blender.job_runner import RUNNING, JobOperator
from addon.blender.train.scene_to_splats import (SavedSettings, prepare_scene_to_splats,
                                           rgba_to_target, scene_to_splats_job)
from addon.core import colour, splat_io
from addon.core.train.trainer import Trainer, TrainConfig, downscaled_view
from addon.core.train.scene_to_splats import (ImageDataset, Points, RandomBackground, orbit_cameras,
                                        sample_surface, sphere_directions)
from tests import bpy_support


# -- Blender-free ----------------------------------------------------------------------------------

def test_sphere_directions_cover_the_sphere() -> None:
    d = sphere_directions(200)
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
    assert np.abs(d.mean(0)).max() < 0.02  # balanced
    assert np.abs(d[:, 2]).max() < 1.0  # never exactly on a pole
    nearest = np.sort(np.linalg.norm(d[:, None] - d[None], axis=2), axis=1)[:, 1]
    assert nearest.max() / nearest.min() < 2.0  # evenly spread
    assert (sphere_directions(50, upper_only=True)[:, 2] > 0).all()


def test_orbit_cameras_frame_the_bounding_sphere(rng) -> None:
    centre, radius = rng.normal(size=3) * 5, 0.7
    cameras = orbit_cameras(centre, radius, 12, 64, 48, distance_factor=2.0)
    for camera in cameras:
        assert np.linalg.norm(camera.centre - centre) == pytest.approx(1.4)
        # Points of the bounding sphere (its silhouette) project inside the frame.
        ring = rng.normal(size=(64, 3))
        ring = centre + radius * ring / np.linalg.norm(ring, axis=1, keepdims=True)
        cam = camera.world_to_camera[:3, :3] @ ring.T + camera.world_to_camera[:3, 3:4]
        u = camera.fx * cam[0] / cam[2] + camera.cx
        v = camera.fy * cam[1] / cam[2] + camera.cy
        assert (u > 0).all() and (u < 64).all() and (v > 0).all() and (v < 48).all()
        c = camera.world_to_camera[:3, :3] @ centre + camera.world_to_camera[:3, 3]
        assert np.allclose(c[:2], 0.0, atol=1e-9) and c[2] > 0  # looks at the centre
    with pytest.raises(ValueError):
        orbit_cameras(centre, radius, 4, 32, 32, distance_factor=0.9)


def test_sample_surface_is_area_weighted_and_on_the_triangles(rng) -> None:
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 2], [3, 0, 2], [0, 3, 2]], float)
    triangles = np.array([[0, 1, 2], [3, 4, 5]])  # areas 0.5 and 4.5
    colours = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    xyz, rgb = sample_surface(vertices, triangles, colours, 20000, rng)
    upper = xyz[:, 2] == 2
    assert upper.mean() == pytest.approx(0.9, abs=0.01)
    assert np.all((xyz[:, 2] == 0) | upper)
    assert np.all(xyz[:, 0] + xyz[:, 1] <= np.where(upper, 3, 1) + 1e-12)
    assert np.all(xyz[:, :2] >= 0)
    assert np.array_equal(rgb[upper], np.tile([0.0, 0.0, 1.0], (upper.sum(), 1)))


def test_image_dataset_composites_over_the_background(rng) -> None:
    camera = orbit_cameras((0, 0, 0), 1.0, 1, 8, 6)[0]
    rgba = rng.random((6, 8, 4)).astype(np.float32)
    rgba[..., :3] *= rgba[..., 3:]
    data = ImageDataset([camera], [rgba], Points(np.zeros((1, 3)), np.ones((1, 3)) * 0.5))
    assert data.train_indices == [0] and data.test_indices == []
    assert np.array_equal(data.image(0), rgba[..., :3])  # black by default

    class _Trainer:
        background = np.zeros(3, np.float32)

    trainer = _Trainer()
    backgrounds = RandomBackground(data, seed=1)
    backgrounds(trainer)
    assert np.array_equal(trainer.background, data.background) and data.background.any()
    assert np.allclose(data.image(0), rgba[..., :3] + (1 - rgba[..., 3:]) * data.background)
    backgrounds.finish(trainer)
    assert not trainer.background.any() and not data.background.any()


def test_coarse_training_targets_follow_the_background(rng) -> None:
    """A bake draws a new background every step: the halved targets of the coarse steps are
    made from the photo over the background of that step, never kept from an earlier one."""
    camera = orbit_cameras((0, 0, 0), 1.0, 1, 128, 96)[0]
    rgba = rng.random((96, 128, 4)).astype(np.float32)
    rgba[..., :3] *= rgba[..., 3:]
    data = ImageDataset([camera], [rgba], Points(rng.normal(size=(20, 3)), np.full((20, 3), 0.5)))
    trainer = Trainer(data, TrainConfig(steps=100, coarse_levels=1, threads=1))
    backgrounds = RandomBackground(data, seed=1)
    for _ in range(2):
        backgrounds(trainer)
        small_camera, small = trainer.training_view(0, 1)
        want = downscaled_view(camera, data.image(0), 2)[1]
        assert np.array_equal(small, want)


def test_render_targets_are_display_srgb(rng) -> None:
    rgba = rng.random((5, 7, 4)).astype(np.float32) * 1.5
    rgba[..., 3] = np.clip(rgba[..., 3], 0, 1)
    rgba[0, 0] = [0.2, 0.2, 0.2, 1.0]
    rgba[0, 1] = [0.1, 0.05, 0.0, 0.5]  # straight colour 0.2, 0.1, 0
    target = rgba_to_target(rgba)
    encoded = 1.055 * 0.2 ** (1 / 2.4) - 0.055
    assert np.allclose(target[0, 0], [encoded] * 3 + [1.0], atol=1e-6)
    assert np.allclose(target[0, 1, 0], 0.5 * encoded, atol=1e-6)
    assert np.all(target[..., :3] <= target[..., 3:] + 1e-6) and np.all(target >= 0)
    inside = np.all(colour.display_from_linear(rgba)[..., :3] <= rgba[..., 3:], axis=-1)
    assert np.allclose(target[inside], colour.display_from_linear(rgba)[inside], atol=1e-6)


# -- bpy ---------------------------------------------------------------------------------------

def _settings(scene) -> tuple:
    r, s = scene.render, scene.render.image_settings
    return (r.engine, r.resolution_x, r.resolution_y, r.resolution_percentage, r.film_transparent,
            r.filepath, r.use_compositing, r.use_border, s.file_format, s.color_depth,
            s.color_mode, scene.cycles.samples, scene.cycles.device, scene.camera,
            len(bpy.data.cameras), sorted(o.name for o in scene.objects if o.hide_render))


def _cube_scene():
    """A red cube (selected and active), a sun, a grey ground, a camera, non-default settings."""
    bpy_support.reset_scene()
    scene = bpy.context.scene
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0.5, 0.2, 0.3))
    cube = bpy.context.active_object
    material = bpy.data.materials.new("Red")
    if material.node_tree is None:
        material.use_nodes = True
    bsdf = next(n for n in material.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    bsdf.inputs["Base Color"].default_value = (0.8, 0.1, 0.05, 1.0)
    cube.data.materials.append(material)
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    scene.collection.objects.link(sun)
    sun.data.energy = 3.0
    bpy.ops.mesh.primitive_plane_add(size=20.0, location=(0, 0, -1))  # not selected: hidden
    ground = bpy.context.active_object
    camera = bpy_support.add_camera(width=320, height=240)
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.render.resolution_percentage = 50
    scene.render.filepath = "//frames/"
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_depth = "8"
    bpy.ops.object.select_all(action="DESELECT")
    cube.select_set(True)
    bpy.context.view_layer.objects.active = cube
    return SimpleNamespace(scene=scene, cube=cube, ground=ground, camera=camera)


def test_bake_cube_to_splats(tmp_path) -> None:
    setup = _cube_scene()
    scene, camera, ground = setup.scene, setup.camera, setup.ground
    before = _settings(scene)
    out = tmp_path / "cube.ply"

    result = bpy.ops.splat.bake_to_splats(cameras=8, resolution=(48, 36), samples=4, steps=100,
                                          max_gaussians=5000, initial_points=800, sh_degree=1,
                                          threads=2, compact=False, filepath=str(out))
    assert result == {"FINISHED"}
    assert _settings(scene) == before and scene.camera == camera and not ground.hide_render
    obj = bpy.context.active_object
    assert obj.splat.is_splat and obj.name == "Cube Splats" and obj["splat_trained_steps"] == 100
    assert obj.splat.source_path == str(out)
    assert np.allclose(np.array(obj.matrix_world), np.eye(4))
    saved = splat_io.load(out)
    held = bpy_support.mesh_gaussians(obj)
    assert bpy_support.gaussians_equal(saved, held)
    low, high = np.array([0.0, -0.3, -0.2]), np.array([1.0, 0.7, 0.8])
    margin = 0.15 * (high - low)
    inside = np.all((saved.means >= low - margin) & (saved.means <= high + margin), axis=1)
    assert inside.all(), f"{(~inside).sum()} of {len(saved)} splats outside the cube's box"
    # The colour is the cube's red (display sRGB), not the grey ground.
    rgb = 0.5 + 0.28209479177387814 * saved.sh[:, 0]
    opacity = 1 / (1 + np.exp(-saved.opacity_logits))
    mean = (rgb * opacity[:, None]).sum(0) / opacity.sum()
    assert mean[0] > 2 * mean[1] and mean[0] > 2 * mean[2]


class _Harness(JobOperator):
    """The operator's modal half without an Operator (no window: events are made by hand)."""

    def __init__(self, key: str) -> None:
        self._key = key
        self.reports: list = []

    def report(self, level, message) -> None:
        self.reports.append((level, message))


def test_bake_in_the_background_stops_on_esc_and_writes_the_ply(tmp_path) -> None:
    setup = _cube_scene()
    before = _settings(setup.scene)
    out = tmp_path / "cube.ply"
    request = prepare_scene_to_splats(bpy.context, cameras=6, resolution=(32, 24), samples=2,
                                      steps=5000, max_gaussians=2000, initial_points=300,
                                      sh_degree=0, threads=2, compact=False, update_every=10,
                                      filepath=str(out))
    assert _settings(setup.scene) == before
    running = scene_to_splats_job(request)
    RUNNING[running.key] = running
    harness = _Harness(running.key)
    running.job.start()
    deadline = time.monotonic() + 30
    def tick():
        return harness.modal(bpy.context, SimpleNamespace(type="TIMER", value="NOTHING"))
    while running.target() is None and time.monotonic() < deadline:
        assert tick() == {"PASS_THROUGH"}
        time.sleep(0.02)
    obj = running.target()
    assert obj is not None and obj.splat.is_splat  # formed during training
    escape = SimpleNamespace(type="ESC", value="PRESS")
    assert harness.modal(bpy.context, escape) == {"RUNNING_MODAL"}
    result = None
    while result != {"FINISHED"} and time.monotonic() < deadline:
        result = tick()
        time.sleep(0.02)
    assert result == {"FINISHED"} and running.key not in RUNNING
    step = running.job.trainer.step
    assert 0 < step < 5000 and obj["splat_trained_steps"] == step
    assert obj.splat.source_path == str(out)
    assert bpy_support.gaussians_equal(splat_io.load(out), bpy_support.mesh_gaussians(obj))
    level, message = harness.reports[-1]
    assert level == {"INFO"} and f"stopped at step {step:,}" in message and str(out) in message


def test_bake_with_nothing_to_bake_changes_nothing() -> None:
    bpy_support.reset_scene()
    before = bpy_support.scene_state()
    with pytest.raises(RuntimeError, match="nothing to bake"):
        bpy.ops.splat.bake_to_splats(cameras=2, resolution=(16, 16), steps=1)
    assert bpy_support.scene_state() == before


def test_saved_settings_restore_in_any_order() -> None:
    bpy_support.ensure_registered()
    settings = bpy.context.scene.render.image_settings
    settings.file_format, settings.color_depth = "PNG", "8"
    saved = SavedSettings()
    saved.remember(settings, "file_format", "color_depth")
    saved.set(settings, "file_format", "OPEN_EXR")  # changes the depth too
    saved.set(settings, "color_depth", "32")
    saved.restore()
    assert (settings.file_format, settings.color_depth) == ("PNG", "8")
