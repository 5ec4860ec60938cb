"""Cameras: Blender camera settings <-> OpenCV pinhole, in plain NumPy (no bpy).

`blender_pipeline_project` below is a literal transcription of Blender's own path from camera
settings to pixels (BKE_camera_sensor_size / BKE_camera_sensor_fit /
BKE_camera_params_compute_viewplane / perspective_m4 / BKE_camera_multiview_model_matrix, then
NDC to pixels), step by step as the C code does it: the slow, obviously-correct twin that the
closed-form `camera_from_blender` is held against. tests/blender/test_cameras_blender.py holds both
against Blender itself.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from addon.core.cameras import (
    BlenderCameraParams,
    Camera,
    camera_from_blender,
    camera_near,
    camera_to_blender,
    unsupported_camera,
)

REL = 1e-9  # round trips are plain float64 algebra


# ----------------------------------------------------------------------------- helpers

def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def random_size(rng: np.random.Generator, low: int = 1, high: int = 4000) -> tuple[int, int]:
    """Landscape, portrait, square, odd and tiny sizes."""
    kind = rng.integers(4)
    w = int(rng.integers(low, high))
    if kind == 0:
        return w, w
    h = int(rng.integers(low, high))
    if kind == 1:
        return max(w, h), min(w, h)
    if kind == 2:
        return min(w, h), max(w, h)
    return w, h


def random_camera(rng: np.random.Generator) -> Camera:
    width, height = random_size(rng)
    fx = float(rng.uniform(0.05, 3.0)) * max(width, height)
    fy = fx * float(np.exp(rng.uniform(np.log(0.25), np.log(4.0))))
    cx = width * float(rng.uniform(-0.5, 1.5))
    cy = height * float(rng.uniform(-0.5, 1.5))
    w2c = np.eye(4)
    w2c[:3, :3] = random_rotation(rng)
    w2c[:3, 3] = rng.uniform(-20, 20, size=3)
    return Camera(w2c, fx, fy, cx, cy, width, height)


def random_blender_params(rng: np.random.Generator, fit: str | None = None) -> BlenderCameraParams:
    matrix_world = np.eye(4)
    scale = np.exp(rng.uniform(np.log(0.2), np.log(5.0), size=3))
    matrix_world[:3, :3] = random_rotation(rng) * scale  # columns scaled: rotation @ diag(scale)
    matrix_world[:3, 3] = rng.uniform(-10, 10, size=3)
    res_x, res_y = random_size(rng, low=4, high=5000)
    percentage = int(rng.choice([100, 50, int(rng.integers(1, 301))]))
    while res_x * percentage // 100 < 1 or res_y * percentage // 100 < 1:
        percentage += 1
    aspects = [1.0, float(rng.uniform(1.0, 4.0))]
    rng.shuffle(aspects)
    if rng.random() < 0.25:
        aspects = list(rng.uniform(1.0, 3.0, size=2))
    return BlenderCameraParams(
        matrix_world=matrix_world,
        lens=float(rng.uniform(1.0, 200.0)),
        sensor_width=float(rng.uniform(2.0, 70.0)),
        sensor_height=float(rng.uniform(2.0, 70.0)),
        sensor_fit=fit or str(rng.choice(["AUTO", "HORIZONTAL", "VERTICAL"])),
        shift_x=float(rng.uniform(-1.5, 1.5)),
        shift_y=float(rng.uniform(-1.5, 1.5)),
        resolution_x=res_x,
        resolution_y=res_y,
        resolution_percentage=percentage,
        pixel_aspect_x=float(aspects[0]),
        pixel_aspect_y=float(aspects[1]),
    )


def project(camera: Camera, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (N, 2) and camera-space z (N,) of world points (N, 3)."""
    cam = points @ camera.world_to_camera[:3, :3].T + camera.world_to_camera[:3, 3]
    z = cam[:, 2]
    u = camera.fx * cam[:, 0] / z + camera.cx
    v = camera.fy * cam[:, 1] / z + camera.cy
    return np.stack([u, v], axis=1), z


def unproject(camera: Camera, pixels: np.ndarray, depth: np.ndarray) -> np.ndarray:
    x = (pixels[:, 0] - camera.cx) / camera.fx * depth
    y = (pixels[:, 1] - camera.cy) / camera.fy * depth
    cam = np.stack([x, y, depth], axis=1)
    return (cam - camera.world_to_camera[:3, 3]) @ np.linalg.inv(camera.world_to_camera[:3, :3]).T


def sample_points(camera: Camera, rng: np.random.Generator, n: int = 200) -> np.ndarray:
    """World points in front of `camera`, over and a little beyond its image."""
    pixels = rng.uniform(-0.2, 1.2, size=(n, 2)) * [camera.width, camera.height]
    depth = np.exp(rng.uniform(np.log(0.3), np.log(100.0), size=n))
    return unproject(camera, pixels, depth)


def blender_pipeline_project(params: BlenderCameraParams, points: np.ndarray,
                             clip_start: float = 0.1, clip_end: float = 100.0) -> np.ndarray:
    """Pixels of world points the way Blender computes them, one C function at a time."""
    # BKE_render_resolution (no crop): integer truncation.
    winx = params.resolution_x * params.resolution_percentage // 100
    winy = params.resolution_y * params.resolution_percentage // 100
    aspx, aspy = params.pixel_aspect_x, params.pixel_aspect_y
    fit_code = {"AUTO": 0, "HORIZONTAL": 1, "VERTICAL": 2}

    # BKE_camera_params_compute_viewplane(params, winx, winy, aspx, aspy), zoom 1, no offset.
    ycor = aspy / aspx
    # BKE_camera_sensor_size: the camera's own fit; for AUTO, sensor_x is both x and y.
    sensor_size = params.sensor_height if fit_code[params.sensor_fit] == 2 else params.sensor_width
    pixsize = sensor_size * clip_start / params.lens
    # BKE_camera_sensor_fit
    fit = fit_code[params.sensor_fit]
    if fit == 0:
        fit = 1 if aspx * winx >= aspy * winy else 2
    viewfac = winx if fit == 1 else ycor * winy
    pixsize /= viewfac
    xmin, xmax = -0.5 * winx, 0.5 * winx
    ymin, ymax = -0.5 * ycor * winy, 0.5 * ycor * winy
    dx = params.shift_x * viewfac
    dy = params.shift_y * viewfac
    xmin, xmax, ymin, ymax = (xmin + dx) * pixsize, (xmax + dx) * pixsize, \
        (ymin + dy) * pixsize, (ymax + dy) * pixsize

    # perspective_m4 (written here row-major: row i, column j)
    winmat = np.zeros((4, 4))
    winmat[0, 0] = 2 * clip_start / (xmax - xmin)
    winmat[1, 1] = 2 * clip_start / (ymax - ymin)
    winmat[0, 2] = (xmax + xmin) / (xmax - xmin)
    winmat[1, 2] = (ymax + ymin) / (ymax - ymin)
    winmat[2, 2] = -(clip_end + clip_start) / (clip_end - clip_start)
    winmat[3, 2] = -1.0
    winmat[2, 3] = -2 * clip_start * clip_end / (clip_end - clip_start)

    # BKE_camera_multiview_model_matrix: object matrix, normalize_m4 (axis lengths only).
    model = params.matrix_world.copy()
    model[:3, :3] /= np.linalg.norm(model[:3, :3], axis=0)
    viewmat = np.linalg.inv(model)

    clip = np.c_[points, np.ones(len(points))] @ (winmat @ viewmat).T
    ndc = clip[:, :2] / clip[:, 3:4]
    return np.stack([(ndc[:, 0] + 1) * 0.5 * winx, (1 - ndc[:, 1]) * 0.5 * winy], axis=1)


def assert_same_camera(a: Camera, b: Camera, rel: float = REL) -> None:
    assert (a.width, a.height) == (b.width, b.height)
    for name in ("fx", "fy"):
        assert getattr(a, name) == pytest.approx(getattr(b, name), rel=rel), name
    size = max(a.width, a.height)
    assert abs(a.cx - b.cx) <= rel * max(size, abs(a.cx))
    assert abs(a.cy - b.cy) <= rel * max(size, abs(a.cy))
    scale = 1.0 + np.abs(a.world_to_camera).max()
    np.testing.assert_allclose(a.world_to_camera, b.world_to_camera, rtol=0, atol=rel * scale)


# ----------------------------------------------------------------------------- round trips

def test_camera_to_blender_and_back(rng):
    for _ in range(500):
        cam = random_camera(rng)
        params = camera_to_blender(cam)
        assert params.sensor_fit == "HORIZONTAL"
        assert params.pixel_aspect_x >= 1 and params.pixel_aspect_y >= 1
        assert min(params.pixel_aspect_x, params.pixel_aspect_y) == 1
        assert params.lens >= 1 and params.sensor_width >= 1
        assert min(params.resolution_x, params.resolution_y) >= 4
        assert params.effective_resolution == (cam.width, cam.height)
        # The Blender camera frame: its columns are unit axes, and it is a rotation.
        axes = params.matrix_world[:3, :3]
        np.testing.assert_allclose(axes.T @ axes, np.eye(3), atol=1e-12)
        assert np.linalg.det(axes) == pytest.approx(1.0)
        assert_same_camera(camera_from_blender(params), cam)
        # sensor_height is the frame's true height: a vertical fit keeps the field of view.
        if params.sensor_height > 1.0:
            vertical = camera_from_blender(dataclasses.replace(params, sensor_fit="VERTICAL"))
            assert (vertical.fx, vertical.fy) == (pytest.approx(cam.fx, rel=REL),
                                                  pytest.approx(cam.fy, rel=REL))


@pytest.mark.parametrize("fit", ["AUTO", "HORIZONTAL", "VERTICAL"])
def test_blender_to_camera_and_back(rng, fit):
    """Random Blender settings (all fits, shifts, pixel aspects, percentages, scaled object
    matrices) -> Camera -> Blender settings (horizontal fit) -> the same Camera."""
    for _ in range(300):
        params = random_blender_params(rng, fit)
        cam = camera_from_blender(params)
        assert_same_camera(camera_from_blender(camera_to_blender(cam)), cam)
        # Both Blender settings render the same pixels.
        points = sample_points(cam, rng, 50)
        np.testing.assert_allclose(blender_pipeline_project(camera_to_blender(cam), points),
                                   blender_pipeline_project(params, points),
                                   rtol=0, atol=1e-8 * max(cam.width, cam.height))


def test_tiny_and_wide_cameras_round_trip(rng):
    for width, height in [(1, 1), (1, 7), (3, 2), (4, 4), (2, 5000)]:
        cam = Camera(np.eye(4), 0.7 * width, 0.9 * width, 0.3, 0.6, width, height)
        params = camera_to_blender(cam)
        assert min(params.resolution_x, params.resolution_y) >= 4
        assert params.resolution_percentage == (25 if min(width, height) < 4 else 100)
        assert_same_camera(camera_from_blender(params), cam)
    # A horizontal field of view wider than Blender's 1 mm lens allows with a 36 mm sensor.
    cam = Camera(np.eye(4), 10.0, 10.0, 500.0, 300.0, 1000, 600)  # about 177.7 degrees
    params = camera_to_blender(cam)
    assert params.lens == 1.0 and params.sensor_width == pytest.approx(100.0)
    assert_same_camera(camera_from_blender(params), cam)


# ----------------------------------------------------------------------------- Blender's formulas

def test_closed_form_matches_blender_pipeline(rng):
    """camera_from_blender projects exactly as Blender's viewplane -> winmat -> NDC chain."""
    for _ in range(500):
        params = random_blender_params(rng)
        cam = camera_from_blender(params)
        points = sample_points(cam, rng, 100)
        pixels, z = project(cam, points)
        assert (z > 0).all()
        clip_start = float(rng.uniform(0.001, 1.0))
        expected = blender_pipeline_project(params, points, clip_start, clip_start * 1000)
        np.testing.assert_allclose(pixels, expected, rtol=0,
                                   atol=1e-9 * max(cam.width, cam.height))


def test_known_values():
    # Blender's default: 50 mm lens, 36 mm sensor, 1920x1080, AUTO: 39.6 degrees horizontally.
    params = BlenderCameraParams(np.eye(4), 50.0, 36.0, 24.0, "AUTO", 0.0, 0.0, 1920, 1080)
    cam = camera_from_blender(params)
    assert cam.fx == pytest.approx(50 * 1920 / 36) and cam.fy == cam.fx
    assert (cam.cx, cam.cy) == (960.0, 540.0)
    assert np.degrees(2 * np.arctan(960 / cam.fx)) == pytest.approx(39.5977, abs=1e-4)

    # AUTO on a portrait frame fits the (36 mm) sensor width to the frame's height.
    portrait = BlenderCameraParams(np.eye(4), 50.0, 36.0, 24.0, "AUTO", 0.0, 0.0, 1080, 1920)
    assert camera_from_blender(portrait).fy == pytest.approx(50 * 1920 / 36)
    # VERTICAL uses the sensor height, HORIZONTAL the width, whatever the frame's shape.
    vertical = BlenderCameraParams(np.eye(4), 50.0, 36.0, 24.0, "VERTICAL", 0.0, 0.0, 1920, 1080)
    assert camera_from_blender(vertical).fy == pytest.approx(50 * 1080 / 24)
    horizontal = BlenderCameraParams(np.eye(4), 50.0, 36.0, 24.0, "HORIZONTAL", 0, 0, 1080, 1920)
    assert camera_from_blender(horizontal).fx == pytest.approx(50 * 1080 / 36)

    # Shift is in units of the fitted frame side: shift_x 0.5 moves the view half a frame
    # right (scene content moves left); shift_y 0.25 on a landscape frame moves it up by a
    # quarter of the frame *width*.
    shifted = BlenderCameraParams(np.eye(4), 50.0, 36.0, 24.0, "AUTO", 0.5, 0.25, 1920, 1080)
    cam = camera_from_blender(shifted)
    assert (cam.cx, cam.cy) == (960.0 - 960.0, 540.0 + 480.0)

    # Pixel aspect 2:1 (wide pixels): same horizontal view, half the pixels per unit in x.
    wide = BlenderCameraParams(np.eye(4), 50.0, 36.0, 24.0, "AUTO", 0.0, 0.0, 960, 1080,
                               pixel_aspect_x=2.0)
    cam = camera_from_blender(wide)
    assert cam.fx == pytest.approx(50 * 960 / 36) and cam.fy == pytest.approx(2 * cam.fx)

    # Percentage truncates like Blender's integer arithmetic.
    odd = BlenderCameraParams(np.eye(4), 50.0, 36.0, 24.0, "AUTO", 0.0, 0.0, 1001, 333,
                              resolution_percentage=37)
    assert odd.effective_resolution == (370, 123)
    assert (camera_from_blender(odd).width, camera_from_blender(odd).height) == (370, 123)


# ----------------------------------------------------------------------------- conventions

def test_blender_axes_to_opencv_axes(rng):
    for _ in range(100):
        params = random_blender_params(rng)
        cam = camera_from_blender(params)
        m = params.matrix_world
        axes = m[:3, :3] / np.linalg.norm(m[:3, :3], axis=0)
        origin = m[:3, 3]
        depth = float(rng.uniform(0.1, 50))
        # A point on the Blender camera's -Z axis is in front: +z, at the principal point.
        (pixel,), (z,) = project(cam, (origin - depth * axes[:, 2])[None])
        assert z == pytest.approx(depth)
        np.testing.assert_allclose(pixel, [cam.cx, cam.cy], atol=1e-9 * max(cam.width, cam.height))
        # Blender's +X is image right, +Y is image up (smaller v).
        (right,), _ = project(cam, (origin - depth * axes[:, 2] + axes[:, 0])[None])
        (up,), _ = project(cam, (origin - depth * axes[:, 2] + axes[:, 1])[None])
        assert right[0] > cam.cx and right[1] == pytest.approx(cam.cy, abs=1e-6)
        assert up[1] < cam.cy and up[0] == pytest.approx(cam.cx, abs=1e-6)
        # Behind the camera: negative z.
        _, (z_back,) = project(cam, (origin + depth * axes[:, 2])[None])
        assert z_back == pytest.approx(-depth)
        # The camera centre is the object's location; the view is rigid (scale dropped).
        np.testing.assert_allclose(cam.centre, origin, atol=1e-9 * (1 + np.abs(origin).max()))
        rot = cam.world_to_camera[:3, :3]
        np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(rot) == pytest.approx(1.0)


def test_identity_blender_camera():
    """Blender's unrotated camera looks down world -Z with +Y up: OpenCV x=X, y=-Y, z=-Z."""
    params = BlenderCameraParams(np.eye(4), 50.0, 36.0, 24.0, "AUTO", 0.0, 0.0, 100, 100)
    np.testing.assert_array_equal(camera_from_blender(params).world_to_camera,
                                  np.diag([1.0, -1.0, -1.0, 1.0]))


def test_look_at(rng):
    for _ in range(100):
        eye = rng.uniform(-10, 10, size=3)
        target = eye + rng.normal(size=3) * rng.uniform(0.5, 10)
        width, height = random_size(rng, low=2)
        fov = float(rng.uniform(10, 150))
        cam = Camera.look_at(eye, target, width=width, height=height, fov_x_degrees=fov)
        rot = cam.world_to_camera[:3, :3]
        np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(rot) == pytest.approx(1.0)
        np.testing.assert_allclose(cam.centre, eye, atol=1e-9)
        (pixel,), (z,) = project(cam, target[None])
        assert z == pytest.approx(np.linalg.norm(target - eye))
        np.testing.assert_allclose(pixel, [width / 2, height / 2], atol=1e-9 * width)
        # The image's left and right edges are fov_x apart.
        assert 2 * np.degrees(np.arctan(0.5 * width / cam.fx)) == pytest.approx(fov)
        # World up (+Z) is image up, unless looking straight along it.
        forward = (target - eye) / np.linalg.norm(target - eye)
        if abs(forward[2]) < 0.99:
            # (a step up small against the distance: a fixed 0.1 went behind a camera looking
            # steeply down at a target nearer than that, seed 1766463868)
            lift = 0.01 * np.linalg.norm(target - eye)
            (above,), _ = project(cam, (target + [0, 0, lift])[None])
            assert above[1] < height / 2
        # Through Blender and back, the same camera.
        assert_same_camera(camera_from_blender(camera_to_blender(cam)), cam)
    # Looking straight down still gives a valid camera.
    cam = Camera.look_at([0, 0, 5], [0, 0, 0], width=64, height=48)
    (pixel,), (z,) = project(cam, np.zeros((1, 3)))
    assert z == pytest.approx(5.0)
    np.testing.assert_allclose(pixel, [32, 24], atol=1e-12)


# ----------------------------------------------------------------------------- errors

def test_invalid_params_raise():
    good = dict(matrix_world=np.eye(4), lens=50.0, sensor_width=36.0, sensor_height=24.0,
                sensor_fit="AUTO", shift_x=0.0, shift_y=0.0, resolution_x=64, resolution_y=48)
    BlenderCameraParams(**good)
    for change in [dict(sensor_fit="FILL"), dict(lens=0.0), dict(sensor_width=-1.0),
                   dict(matrix_world=np.eye(3)), dict(lens=float("nan")),
                   dict(matrix_world=np.full((4, 4), np.inf)), dict(resolution_x=0),
                   dict(resolution_percentage=0), dict(pixel_aspect_x=0.0),
                   dict(resolution_x=10.5)]:
        with pytest.raises(ValueError):
            BlenderCameraParams(**{**good, **change})
    with pytest.raises(ValueError, match="too small"):
        camera_from_blender(BlenderCameraParams(**{**good, "resolution_percentage": 1}))
    with pytest.raises(ValueError, match="zero-length"):
        camera_from_blender(BlenderCameraParams(**{**good, "matrix_world": np.diag([1, 0, 1, 1])}))
    with pytest.raises(ValueError, match="pixel aspect"):
        camera_to_blender(Camera(np.eye(4), 1000.0, 1.0, 32, 24, 64, 48))


# ------------------------------------------------------------- orthographic and panoramic

def blender_ortho_pipeline_project(params: BlenderCameraParams, points: np.ndarray) -> np.ndarray:
    """Pixels of world points through an orthographic Blender camera, step by step:
    BKE_camera_params_compute_viewplane with pixsize = ortho_scale, then orthographic_m4."""
    winx = params.resolution_x * params.resolution_percentage // 100
    winy = params.resolution_y * params.resolution_percentage // 100
    aspx, aspy = params.pixel_aspect_x, params.pixel_aspect_y
    ycor = aspy / aspx
    fit = params.sensor_fit
    if fit == "AUTO":
        fit = "HORIZONTAL" if aspx * winx >= aspy * winy else "VERTICAL"
    viewfac = winx if fit == "HORIZONTAL" else ycor * winy
    pixsize = params.ortho_scale / viewfac
    dx, dy = params.shift_x * viewfac, params.shift_y * viewfac
    xmin, xmax = (-0.5 * winx + dx) * pixsize, (0.5 * winx + dx) * pixsize
    ymin, ymax = (-0.5 * ycor * winy + dy) * pixsize, (0.5 * ycor * winy + dy) * pixsize
    model = params.matrix_world.copy()
    model[:3, :3] /= np.linalg.norm(model[:3, :3], axis=0)
    view = np.c_[points, np.ones(len(points))] @ np.linalg.inv(model).T  # Blender camera frame
    ndc_x = (2 * view[:, 0] - (xmax + xmin)) / (xmax - xmin)
    ndc_y = (2 * view[:, 1] - (ymax + ymin)) / (ymax - ymin)
    return np.stack([(ndc_x + 1) * 0.5 * winx, (1 - ndc_y) * 0.5 * winy], axis=1)


@pytest.mark.parametrize("fit", ["AUTO", "HORIZONTAL", "VERTICAL"])
def test_orthographic_camera_matches_blender_pipeline(rng, fit):
    for _ in range(20):
        params = dataclasses.replace(random_blender_params(rng, fit), type="ORTHO",
                                     ortho_scale=float(rng.uniform(0.1, 50.0)), clip_end=77.0)
        camera = camera_from_blender(params)
        assert camera.model == "ORTHO" and camera.far == 77.0
        points = rng.uniform(-30, 30, size=(50, 3))
        cam = points @ camera.world_to_camera[:3, :3].T + camera.world_to_camera[:3, 3]
        ours = np.stack([camera.fx * cam[:, 0] + camera.cx, camera.fy * cam[:, 1] + camera.cy], 1)
        want = blender_ortho_pipeline_project(params, points)
        np.testing.assert_allclose(ours, want, rtol=1e-9, atol=1e-7 * max(camera.width, camera.height))


def test_orthographic_scale_spans_the_fitted_side():
    params = BlenderCameraParams(np.eye(4), 50, 36, 24, "AUTO", 0, 0, 200, 100, type="ORTHO",
                                 ortho_scale=4.0)
    camera = camera_from_blender(params)
    assert camera.fx == pytest.approx(50.0) and camera.fy == pytest.approx(50.0)
    assert (camera.cx, camera.cy) == (100.0, 50.0)


def test_panoramic_cameras_from_blender():
    base = dict(matrix_world=np.eye(4), lens=50, sensor_width=36, sensor_height=24,
                sensor_fit="AUTO", shift_x=0.1, shift_y=-0.2, resolution_x=400,
                resolution_y=200, type="PANO", clip_end=50.0)
    equirect = camera_from_blender(BlenderCameraParams(
        **base, panorama_type="EQUIRECTANGULAR", latitude_min=-1.0, latitude_max=1.2,
        longitude_min=-2.0, longitude_max=3.0))
    assert equirect.model == "EQUIRECTANGULAR" and equirect.params == (-2.0, 3.0, -1.0, 1.2)
    # u = col / W + shift_x, v = row_from_bottom / H + shift_y
    assert (equirect.fx, equirect.cx) == (400.0, -40.0)
    assert (equirect.fy, equirect.cy) == (200.0, pytest.approx(160.0))
    assert equirect.far == 50.0
    solid = camera_from_blender(BlenderCameraParams(
        **base, panorama_type="FISHEYE_EQUISOLID", fisheye_lens=8.0, fisheye_fov=3.0))
    assert solid.params == (8.0, 3.0, 36.0, 18.0)  # horizontal fit: height from the aspect
    vertical = camera_from_blender(BlenderCameraParams(
        **{**base, "sensor_fit": "VERTICAL"}, panorama_type="FISHEYE_EQUISOLID"))
    assert vertical.params[2:] == (48.0, 24.0)
    assert camera_from_blender(BlenderCameraParams(
        **base, panorama_type="MIRRORBALL")).params == ()
    assert camera_from_blender(BlenderCameraParams(
        **base, panorama_type="FISHEYE_EQUIDISTANT", fisheye_fov=4.0)).params == (4.0,)
    face = camera_from_blender(BlenderCameraParams(**base, panorama_type="EQUIANGULAR_CUBEMAP_FACE"))
    assert face.model == "EQUIANGULAR_CUBEMAP_FACE" and face.params == ()
    assert (face.fx, face.cx, face.fy) == (400.0, -40.0, 200.0)
    # Cycles divides the heights by the cylinder's radius (blender_camera_sync)
    cylinder = camera_from_blender(BlenderCameraParams(
        **base, panorama_type="CENTRAL_CYLINDRICAL", central_cylindrical_range_u_min=-2.0,
        central_cylindrical_range_u_max=2.5, central_cylindrical_range_v_min=-1.0,
        central_cylindrical_range_v_max=3.0, central_cylindrical_radius=2.0))
    assert cylinder.model == "CENTRAL_CYLINDRICAL"
    assert cylinder.params == (-2.0, 2.5, -0.5, 1.5)
    assert camera_from_blender(BlenderCameraParams(
        **base, panorama_type="CENTRAL_CYLINDRICAL")).params == (-np.pi, np.pi, -1.0, 1.0)
    for empty in (dict(central_cylindrical_range_u_max=-np.pi),
                  dict(central_cylindrical_range_v_min=1.0)):
        with pytest.raises(ValueError, match="range is empty"):
            camera_from_blender(BlenderCameraParams(
                **base, panorama_type="CENTRAL_CYLINDRICAL", **empty))
    with pytest.raises(ValueError, match="central_cylindrical_radius"):
        BlenderCameraParams(**base, panorama_type="CENTRAL_CYLINDRICAL",
                            central_cylindrical_radius=0.0)


@pytest.mark.parametrize("kind", ["SOME_FUTURE_PANORAMA"])  # every type Blender 4.2-5.3 has renders
def test_unsupported_panoramas_say_so(kind):
    params = BlenderCameraParams(np.eye(4), 50, 36, 24, "AUTO", 0, 0, 64, 32, type="PANO",
                                 panorama_type=kind)
    reason = unsupported_camera(params)
    assert reason and kind.replace("_", " ").lower() in reason
    with pytest.raises(ValueError, match="not supported"):
        camera_from_blender(params)


def test_camera_near_for_each_type():
    params = BlenderCameraParams(np.eye(4), 50, 36, 24, "AUTO", 0, 0, 64, 32, clip_start=0.5)
    assert camera_near(params, 0.01) == 0.01
    assert camera_near(dataclasses.replace(params, type="ORTHO"), 0.01) == 0.5
    assert camera_near(dataclasses.replace(params, type="PANO"), 2.0) == 2.0


def test_only_pinholes_become_blender_settings():
    with pytest.raises(ValueError, match="pinhole"):
        camera_to_blender(Camera(np.eye(4), 10, 10, 5, 5, 10, 10, model="ORTHO"))
