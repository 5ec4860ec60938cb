"""Cameras against Blender itself (bpy): `camera_from_blender` and `camera_to_blender` must
project world points exactly where Blender's render does.

What counts as "Blender's projection" here is all Blender's own code, captured at render time
by a probe render engine (a `RenderEngine` whose `render()` only records, so a "render" costs
well under a millisecond):

- the render size: `RenderEngine.resolution_x/y` (the render pipeline's `winx, winy`, i.e.
  resolution x percentage / 100 after Blender's integer truncation);
- the camera pose: `RenderEngine.camera_model_matrix` (`BKE_camera_multiview_model_matrix`:
  the object matrix with its axes normalised);
- the window matrix: `Object.calc_matrix_camera(depsgraph, x, y, scale_x, scale_y)`, called
  the way `RE_SetCamera` computes the render's window matrix: render size `winx, winy` and
  the scene's pixel aspect (`BKE_camera_params_compute_viewplane(params, re->winx, re->winy,
  re->r.xasp, re->r.yasp)`), with the evaluated camera.

Pixels from Blender's matrices: `ndc = (winmat @ inverse(model) @ X)` after the divide,
`u = (ndc_x + 1) W / 2`, `v = (1 - ndc_y) H / 2` (NDC -1 is the outer edge of pixel 0).

Tolerance: Blender computes and stores everything in float32 (about 6e-8 relative), so each
point's pixel error is measured against the size that rounding is relative to:
`E = max(W, H, |cx|, |cy|, |u|, |v|) + max(fx, fy) * (1 + (x/z)^2 + (y/z)^2)` (the first
term from the window matrix and the pixel mapping; the second from the view rotation, whose
float32 error of ~1e-7 rad moves a pixel by fx * (1 + (x/z)^2) * angle, a lot for wide
angles far off axis). Where Blender holds our float64 pose in float32 (camera_to_blender) or
transforms points in float32 (bpy_extras), a position error of ~6e-8 |X| moves a pixel by
fx * 6e-8 |X| / z, so E also gets `max(fx, fy) * (|X| + |camera centre|) / z` there. The
check is |du|, |dv| <= 1e-6 * E: a relative 1e-6, about ten times the float32 noise seen
(worst about 1e-7 E for camera_from_blender over thousands of random cameras). A camera set
from camera_to_blender(c) is compared with c itself, whose float64 numbers Blender stores
rounded to float32 (lens, shifts, pixel aspect, pose: several roundings that add up): there
too the bound is 1e-6 * E (worst seen 2.6e-7 E over 25 runs of 200 cameras), and reading that
Blender camera back through camera_from_blender matches Blender's projection to the same 1e-6.
The pose is stored as a quaternion (`camera_adapter.set_camera`): as Euler angles, a view near
gimbal lock came back 3.9e-6 E off (`test_pose_near_gimbal_lock_is_kept`).
"""

from __future__ import annotations

import math

import bpy  # slow to import (seconds): keep every bpy-level camera test in this one module
import mathutils
import numpy as np
import pytest
from bpy_extras.object_utils import world_to_camera_view

from addon.blender.camera_adapter import set_camera
from addon.core.cameras import BlenderCameraParams, Camera, camera_from_blender, camera_to_blender

REL = 1e-6  # of the error scale E; see the module docstring


class _ProbeEngine(bpy.types.RenderEngine):
    """Records what the render pipeline sees for the scene camera; draws nothing."""

    bl_idname = "SPLAT_TEST_CAMERA_PROBE"
    bl_label = "Camera probe (tests)"
    recorded: dict = {}

    def render(self, depsgraph):
        scene = depsgraph.scene
        camera = scene.camera  # evaluated
        width, height = self.resolution_x, self.resolution_y
        render = scene.render
        _ProbeEngine.recorded = {
            "size": (width, height),
            "model": np.array(self.camera_model_matrix(camera, use_spherical_stereo=False),
                              dtype=np.float64),
            "winmat": np.array(camera.calc_matrix_camera(
                depsgraph, x=width, y=height,
                scale_x=render.pixel_aspect_x, scale_y=render.pixel_aspect_y), dtype=np.float64),
        }


@pytest.fixture(scope="module")
def blender_scene():
    bpy.utils.register_class(_ProbeEngine)
    scene = bpy.data.scenes.new("camera_test")
    scene.render.engine = _ProbeEngine.bl_idname
    parent = bpy.data.objects.new("camera_parent", None)
    camera = bpy.data.objects.new("camera_test", bpy.data.cameras.new("camera_test"))
    for obj in (parent, camera):
        scene.collection.objects.link(obj)
    scene.camera = camera
    yield scene, camera, parent
    bpy.data.objects.remove(camera)
    bpy.data.objects.remove(parent)
    bpy.data.scenes.remove(scene)
    bpy.utils.unregister_class(_ProbeEngine)


def render_probe(scene) -> dict:
    _ProbeEngine.recorded = {}
    with bpy.context.temp_override(scene=scene):
        bpy.ops.render.render(scene=scene.name)
    assert _ProbeEngine.recorded, "the probe engine did not run"
    return _ProbeEngine.recorded


def evaluated_camera(camera_obj, scene):
    """The camera object as evaluated by the scene's depsgraph (its world matrix current)."""
    view_layer = scene.view_layers[0]
    view_layer.update()
    return camera_obj.evaluated_get(view_layer.depsgraph)


def params_from_bpy(camera_obj, scene) -> BlenderCameraParams:
    """What a Blender-side caller reads off the (evaluated) camera object and the scene."""
    cam, render = camera_obj.data, scene.render
    assert cam.type == "PERSP"
    return BlenderCameraParams(
        matrix_world=np.array(camera_obj.matrix_world, dtype=np.float64),
        lens=cam.lens, sensor_width=cam.sensor_width, sensor_height=cam.sensor_height,
        sensor_fit=cam.sensor_fit, shift_x=cam.shift_x, shift_y=cam.shift_y,
        resolution_x=render.resolution_x, resolution_y=render.resolution_y,
        resolution_percentage=render.resolution_percentage,
        pixel_aspect_x=render.pixel_aspect_x, pixel_aspect_y=render.pixel_aspect_y,
    )


def set_bpy_camera(camera_obj, scene, params: BlenderCameraParams) -> None:
    """Apply `params` to a parentless camera object and the scene's render settings."""
    render = scene.render
    camera_obj.parent = None
    set_camera(camera_obj, params)
    for name in ("resolution_x", "resolution_y", "resolution_percentage",
                 "pixel_aspect_x", "pixel_aspect_y"):
        setattr(render, name, getattr(params, name))


def randomize_bpy_camera(rng, camera_obj, parent, scene, fit: str) -> None:
    cam, render = camera_obj.data, scene.render
    cam.type = "PERSP"
    cam.lens = float(rng.uniform(1.0, 250.0))
    cam.sensor_width = float(rng.uniform(1.0, 70.0))
    cam.sensor_height = float(rng.uniform(1.0, 70.0))
    cam.sensor_fit = fit
    cam.shift_x = float(rng.uniform(-2.0, 2.0))
    cam.shift_y = float(rng.uniform(-2.0, 2.0))
    cam.clip_start = float(rng.uniform(0.001, 1.0))
    cam.clip_end = cam.clip_start * float(rng.uniform(10, 1e4))

    kind = rng.integers(4)  # landscape, portrait, square, anything (odd sizes included)
    a, b = (int(v) for v in rng.integers(4, 4001, size=2))
    res_x, res_y = [(max(a, b), min(a, b)), (min(a, b), max(a, b)), (a, a), (a, b)][kind]
    render.resolution_x, render.resolution_y = res_x, res_y
    percentage = int(rng.choice([100, 50, 33, int(rng.integers(1, 250))]))
    while res_x * percentage // 100 < 1 or res_y * percentage // 100 < 1:
        percentage += 1
    render.resolution_percentage = percentage
    aspect = [1.0, float(rng.uniform(1.0, 4.0))]
    rng.shuffle(aspect)
    if rng.random() < 0.2:
        aspect = [float(v) for v in rng.uniform(1.0, 3.0, size=2)]
    render.pixel_aspect_x, render.pixel_aspect_y = aspect

    camera_obj.location = rng.uniform(-10, 10, size=3).tolist()
    camera_obj.rotation_mode = "XYZ"  # `set_camera` (other tests) leaves it a quaternion
    camera_obj.rotation_euler = rng.uniform(-math.pi, math.pi, size=3).tolist()
    camera_obj.scale = np.exp(rng.uniform(np.log(0.2), np.log(5.0), size=3)).tolist()
    # Sometimes under a rotated, non-uniformly scaled parent: the world matrix is sheared.
    if rng.random() < 0.3:
        parent.location = rng.uniform(-5, 5, size=3).tolist()
        parent.rotation_euler = rng.uniform(-math.pi, math.pi, size=3).tolist()
        parent.scale = np.exp(rng.uniform(np.log(0.5), np.log(2.0), size=3)).tolist()
        camera_obj.parent = parent
    else:
        camera_obj.parent = None


def blender_pixels(probe: dict, points: np.ndarray) -> np.ndarray:
    width, height = probe["size"]
    clip = np.c_[points, np.ones(len(points))] @ (probe["winmat"] @ np.linalg.inv(probe["model"])).T
    ndc = clip[:, :2] / clip[:, 3:4]
    return np.stack([(ndc[:, 0] + 1) * 0.5 * width, (1 - ndc[:, 1]) * 0.5 * height], axis=1)


def camera_pixels(camera: Camera, points: np.ndarray) -> np.ndarray:
    cam = points @ camera.world_to_camera[:3, :3].T + camera.world_to_camera[:3, 3]
    return np.stack([camera.fx * cam[:, 0] / cam[:, 2] + camera.cx,
                     camera.fy * cam[:, 1] / cam[:, 2] + camera.cy], axis=1)


def sample_points(camera: Camera, rng, n: int = 100) -> np.ndarray:
    """World points in front of `camera`, over and a little beyond its image."""
    pixels = rng.uniform(-0.2, 1.2, size=(n, 2)) * [camera.width, camera.height]
    depth = np.exp(rng.uniform(np.log(0.5), np.log(200.0), size=n))
    cam = np.stack([(pixels[:, 0] - camera.cx) / camera.fx * depth,
                    (pixels[:, 1] - camera.cy) / camera.fy * depth, depth], axis=1)
    return (cam - camera.world_to_camera[:3, 3]) @ np.linalg.inv(camera.world_to_camera[:3, :3]).T


def error_scale(camera: Camera, pixels: np.ndarray, points: np.ndarray | None) -> np.ndarray:
    """Per point, the size float32 rounding is relative to (see the module docstring)."""
    a = (pixels[:, 0] - camera.cx) / camera.fx  # x / z
    b = (pixels[:, 1] - camera.cy) / camera.fy  # y / z
    image = np.maximum.reduce([np.full(len(pixels), float(max(camera.width, camera.height))),
                               np.abs(pixels[:, 0]), np.abs(pixels[:, 1]),
                               np.full(len(pixels), max(abs(camera.cx), abs(camera.cy)))])
    angular = 1 + a * a + b * b
    if points is not None:  # positions rounded to float32, or transformed in float32
        z = points @ camera.world_to_camera[2, :3] + camera.world_to_camera[2, 3]
        angular += (np.linalg.norm(points, axis=1) + np.linalg.norm(camera.centre)) / z
    return image + max(camera.fx, camera.fy) * angular


def pixel_error(camera: Camera, ours: np.ndarray, theirs: np.ndarray,
                points: np.ndarray | None = None) -> float:
    """The worst |ours - theirs| in units of `error_scale`; NaN never passes."""
    err = np.abs(ours - theirs).max(axis=1) / error_scale(camera, ours, points)
    return float(err.max()) if np.isfinite(err).all() else float("inf")


@pytest.mark.parametrize("fit", ["AUTO", "HORIZONTAL", "VERTICAL"])
def test_camera_from_blender_matches_blender(blender_scene, rng, fit):
    scene, camera_obj, parent = blender_scene
    worst = 0.0
    for _ in range(150):
        randomize_bpy_camera(rng, camera_obj, parent, scene, fit)
        probe = render_probe(scene)
        params = params_from_bpy(evaluated_camera(camera_obj, scene), scene)
        camera = camera_from_blender(params)

        # The render size is Blender's truncated percentage.
        assert probe["size"] == params.effective_resolution == (camera.width, camera.height)
        # The view: object axes normalised, as the render pipeline does (float32 there).
        np.testing.assert_allclose(np.linalg.inv(camera.world_to_camera) @ np.diag([1, -1, -1, 1]),
                                   probe["model"], rtol=0,
                                   atol=1e-6 * (1 + np.abs(probe["model"]).max()))
        # Pixels through Blender's own window and model matrices.
        points = sample_points(camera, rng)
        err = pixel_error(camera, camera_pixels(camera, points), blender_pixels(probe, points))
        assert err <= REL, (err, params)
        worst = max(worst, err)
    print(f"{fit}: worst pixel error {worst:.2e} of the error scale")


def test_camera_to_blender_matches_blender(blender_scene, rng):
    """A Blender camera set from camera_to_blender(c) renders what c renders."""
    scene, camera_obj, _ = blender_scene
    worst = 0.0
    # Sizes below Blender's minimum resolution of 4 go through the percentage; then random.
    tiny = [(1, 1), (1, 3), (2, 2), (3, 5), (4, 4), (5, 3), (2, 3001)]
    for i in range(200):
        kind = rng.integers(4)
        a, b = (int(v) for v in rng.integers(1, 3001, size=2))
        width, height = [(max(a, b), min(a, b)), (min(a, b), max(a, b)), (a, a), (a, b)][kind]
        if i < len(tiny):
            width, height = tiny[i]
        fx = float(rng.uniform(0.05, 3.0)) * max(width, height)
        fy = fx * float(np.exp(rng.uniform(np.log(0.25), np.log(4.0))))
        rot = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        rot *= np.sign(np.linalg.det(rot))
        w2c = np.eye(4)
        w2c[:3, :3] = rot
        w2c[:3, 3] = rng.uniform(-10, 10, size=3)
        cx, cy = width * rng.uniform(-0.5, 1.5), height * rng.uniform(-0.5, 1.5)
        camera = Camera(w2c, fx, fy, cx, cy, width, height)

        set_bpy_camera(camera_obj, scene, camera_to_blender(camera))
        probe = render_probe(scene)
        assert probe["size"] == (width, height)
        points = sample_points(camera, rng)
        err = pixel_error(camera, camera_pixels(camera, points), blender_pixels(probe, points),
                          points)
        assert err <= REL, (err, camera)
        worst = max(worst, err)
        # Read back from Blender (float32 storage): the same camera, and exactly Blender's view.
        back = camera_from_blender(params_from_bpy(evaluated_camera(camera_obj, scene), scene))
        assert pixel_error(back, camera_pixels(back, points), blender_pixels(probe, points)) <= REL
        for name in ("fx", "fy"):
            assert getattr(back, name) == pytest.approx(getattr(camera, name), rel=1e-6)
        scale = max(width, height, abs(camera.cx), abs(camera.cy))
        assert abs(back.cx - camera.cx) <= 1e-6 * scale and abs(back.cy - camera.cy) <= 1e-6 * scale
    print(f"worst pixel error {worst:.2e} of the error scale")


@pytest.mark.parametrize("pitch", [math.pi / 2 - 3e-4, -math.pi / 2 + 1e-5, math.pi / 2])
def test_pose_near_gimbal_lock_is_kept(blender_scene, rng, pitch):
    """A view whose Euler XYZ decomposition is ill-conditioned (Y rotation near +-90 degrees)
    keeps its pose to float32 rounding: the case of a random camera that came back 0.13 px off
    when the pose went through Euler angles."""
    scene, camera_obj, _ = blender_scene
    euler = mathutils.Euler((float(rng.uniform(-math.pi, math.pi)), pitch,
                             float(rng.uniform(-math.pi, math.pi))), "XYZ")
    camera_to_world = np.eye(4)
    camera_to_world[:3, :3] = np.array(euler.to_matrix(), np.float64) @ np.diag([1, -1, -1])
    camera_to_world[:3, 3] = rng.uniform(-10, 10, size=3)
    camera = Camera(np.linalg.inv(camera_to_world), 4746.06, 14950.73, 70.34, -94.15, 2354, 1007)
    set_bpy_camera(camera_obj, scene, camera_to_blender(camera))
    probe = render_probe(scene)
    points = sample_points(camera, rng)
    err = pixel_error(camera, camera_pixels(camera, points), blender_pixels(probe, points), points)
    assert err <= REL, err


def test_world_to_camera_view_agrees(blender_scene, rng):
    """bpy_extras' world_to_camera_view (Blender's view_frame path, scene resolution at 100 %)
    puts points where our Camera does."""
    scene, camera_obj, parent = blender_scene
    for fit in ("AUTO", "HORIZONTAL", "VERTICAL"):
        for _ in range(20):
            randomize_bpy_camera(rng, camera_obj, parent, scene, fit)
            camera_obj.parent = None
            scene.render.resolution_percentage = 100
            evaluated = evaluated_camera(camera_obj, scene)
            camera = camera_from_blender(params_from_bpy(evaluated, scene))
            points = sample_points(camera, rng, 20)
            frame = np.array([tuple(world_to_camera_view(scene, evaluated, mathutils.Vector(p)))
                              for p in points])
            theirs = np.stack([frame[:, 0] * camera.width, (1 - frame[:, 1]) * camera.height], 1)
            err = pixel_error(camera, camera_pixels(camera, points), theirs, points)
            assert err <= REL, err
