"""Pinhole cameras in the COLMAP/OpenCV convention (x right, y down, z forward).

A pixel's centre is at (i + 0.5, j + 0.5). This module is the one place that converts to and
from Blender's camera parameters (`BlenderCameraParams`, `camera_from_blender`,
`camera_to_blender`); the formulas are written out once, in `camera_from_blender`'s docstring.
Plain numbers and numpy only: no bpy, no mathutils.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Blender's camera frame (looks down -Z, +Y up) to OpenCV's (looks down +Z, +Y down) and back:
# the one definition of that axis flip (it is its own inverse). A Blender camera's matrix_world
# is `camera_to_world @ CAMERA_AXIS_FLIP`; a Blender view matrix becomes an OpenCV
# world_to_camera as `CAMERA_AXIS_FLIP @ view_matrix`.
CAMERA_AXIS_FLIP = np.diag([1.0, -1.0, -1.0, 1.0])
_SENSOR_FITS = ("AUTO", "HORIZONTAL", "VERTICAL")
_MIN_RESOLUTION, _MAX_RESOLUTION = 4, 65536  # Blender's limits on resolution_x, resolution_y


@dataclass
class Camera:
    world_to_camera: np.ndarray  # (4, 4) float64, rigid
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        m = np.array(self.world_to_camera, dtype=np.float64)
        if m.shape != (4, 4):
            raise ValueError(f"world_to_camera must be 4x4, got shape {m.shape}")
        self.world_to_camera = m
        self.fx, self.fy, self.cx, self.cy = (float(v) for v in (self.fx, self.fy, self.cx, self.cy))
        self.width, self.height = int(self.width), int(self.height)
        values = np.append(m.ravel(), [self.fx, self.fy, self.cx, self.cy])
        if not np.isfinite(values).all():
            raise ValueError("camera has non-finite pose or intrinsics")
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")

    @property
    def camera_to_world(self) -> np.ndarray:
        return np.linalg.inv(self.world_to_camera)

    @property
    def centre(self) -> np.ndarray:
        """Camera centre in world coordinates."""
        r, t = self.world_to_camera[:3, :3], self.world_to_camera[:3, 3]
        return -r.T @ t

    @classmethod
    def look_at(cls, eye, target, up=(0.0, 0.0, 1.0), *, width: int, height: int,
                fov_x_degrees: float = 60.0) -> "Camera":
        """A centred pinhole camera at `eye` looking at `target`, `up` pointing up in the image."""
        eye, target, up = (np.asarray(v, np.float64) for v in (eye, target, up))
        forward = target - eye
        forward /= np.linalg.norm(forward)
        right = np.cross(forward, up)
        if np.linalg.norm(right) < 1e-12:  # looking along `up`: any perpendicular will do
            right = np.cross(forward, np.eye(3)[np.argmin(np.abs(forward))])
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        w2c = np.eye(4)
        w2c[:3, :3] = np.stack([right, down, forward])
        w2c[:3, 3] = -w2c[:3, :3] @ eye
        fx = 0.5 * width / np.tan(np.radians(fov_x_degrees) / 2)
        return cls(w2c, fx, fx, width / 2, height / 2, width, height)


@dataclass
class BlenderCameraParams:
    """What Blender's camera object, camera data and render settings say about a view.

    Perspective cameras only (Blender camera data with `type == 'PERSP'`): orthographic and
    panoramic cameras have no pinhole model and are not represented here. Mono views only:
    stereo 3D's extra interocular shift is not modelled, nor are border crop and viewport
    zoom/offset.

    matrix_world: (4, 4) camera-to-world of the camera object, Blender camera frame (looks down
        its local -Z, +Y up in the image). It may carry scale (also negative or from a parent);
        Blender normalises the three axes before inverting it for the view, and so do we.
    lens: focal length in mm. sensor_width, sensor_height: in mm.
    sensor_fit: 'AUTO' | 'HORIZONTAL' | 'VERTICAL'.
    shift_x, shift_y: lens shift in units of the fitted sensor size.
    resolution_x, resolution_y, resolution_percentage: the scene's output size; the rendered
        image is `resolution * percentage // 100` pixels (integer truncation, as Blender does).
    pixel_aspect_x, pixel_aspect_y: Blender keeps both in [1, 200].
    """

    matrix_world: np.ndarray
    lens: float
    sensor_width: float
    sensor_height: float
    sensor_fit: str
    shift_x: float
    shift_y: float
    resolution_x: int
    resolution_y: int
    resolution_percentage: int = 100
    pixel_aspect_x: float = 1.0
    pixel_aspect_y: float = 1.0

    def __post_init__(self) -> None:
        m = np.array(self.matrix_world, dtype=np.float64)
        if m.shape != (4, 4):
            raise ValueError(f"matrix_world must be 4x4, got shape {m.shape}")
        self.matrix_world = m
        for name in ("lens", "sensor_width", "sensor_height", "shift_x", "shift_y",
                     "pixel_aspect_x", "pixel_aspect_y"):
            value = float(getattr(self, name))
            if not np.isfinite(value):
                raise ValueError(f"{name} must be finite, got {value}")
            setattr(self, name, value)
        for name in ("resolution_x", "resolution_y", "resolution_percentage"):
            value = getattr(self, name)
            if int(value) != value:
                raise ValueError(f"{name} must be an integer, got {value}")
            setattr(self, name, int(value))
        if not np.isfinite(m).all():
            raise ValueError("matrix_world has non-finite entries")
        self.sensor_fit = str(self.sensor_fit)
        if self.sensor_fit not in _SENSOR_FITS:
            raise ValueError(f"sensor_fit must be one of {_SENSOR_FITS}, got {self.sensor_fit!r}")
        for name in ("lens", "sensor_width", "sensor_height", "pixel_aspect_x", "pixel_aspect_y"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        for name in ("resolution_x", "resolution_y", "resolution_percentage"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1, got {getattr(self, name)}")

    @property
    def effective_resolution(self) -> tuple[int, int]:
        """The rendered image size in pixels (Blender's `BKE_render_resolution` without crop)."""
        width = self.resolution_x * self.resolution_percentage // 100
        height = self.resolution_y * self.resolution_percentage // 100
        return width, height


def camera_from_blender(params: BlenderCameraParams) -> Camera:
    """The pinhole `Camera` that renders exactly what Blender renders for `params`.

    This follows Blender's own code (blenkernel/intern/camera.cc): `BKE_camera_sensor_size`,
    `BKE_camera_sensor_fit` and `BKE_camera_params_compute_viewplane` (zoom 1, no offset, as
    for a camera object at render time, called from `RE_SetCamera` with the render size
    `winx, winy` and the pixel aspect `aspx, aspy`), then `perspective_m4` on that viewplane;
    and `BKE_camera_multiview_model_matrix` (the object matrix with its axes normalised) for
    the pose. Cycles' `blender_camera_viewplane` computes the same view.

    Intrinsics (W, H: the effective resolution):

        W, H    = resolution_x * percentage // 100, resolution_y * percentage // 100
        aspx, aspy = pixel_aspect_x, pixel_aspect_y;   ycor = aspy / aspx
        sensor  = sensor_height if sensor_fit == 'VERTICAL' else sensor_width
                  (the camera's own setting: AUTO always uses sensor_width)
        fit     = sensor_fit, except AUTO: HORIZONTAL if aspx*W >= aspy*H else VERTICAL
        viewfac = W if fit == HORIZONTAL else ycor * H
        fx      = lens * viewfac / sensor
        fy      = fx / ycor
        cx      = W/2 - shift_x * viewfac
        cy      = H/2 + shift_y * viewfac / ycor

    (Derivation: Blender's viewplane at depth `clip_start` is `pixsize * [-W/2 + dx, W/2 + dx]`
    by `pixsize * [-ycor*H/2 + dy, ycor*H/2 + dy]`, with `pixsize = sensor * clip_start /
    (lens * viewfac)` and `(dx, dy) = (shift_x, shift_y) * viewfac`. Its perspective matrix maps
    the viewplane onto NDC [-1, 1]^2, and pixels are `u = (ndc_x + 1) W/2`,
    `v = (1 - ndc_y) H/2`, so NDC -1 is the outer edge of pixel 0 and pixel i spans [i, i+1],
    centre i + 0.5: the same convention as `Camera`. `clip_start` cancels.)

    Pose: with `N` = matrix_world with each of its three axis columns scaled to unit length,

        world_to_camera = inverse(N @ diag(1, -1, -1, 1))

    which turns Blender's camera frame (-Z forward, +Y up) into OpenCV's (+Z forward, +Y down).
    Like Blender, only lengths are normalised: a sheared parent chain gives a non-rigid view
    matrix and a negative scale a mirrored one, exactly as Blender renders them.
    """
    width, height = params.effective_resolution
    if width < 1 or height < 1:
        raise ValueError(
            f"render size {params.resolution_x}x{params.resolution_y} at "
            f"{params.resolution_percentage}% is {width}x{height} pixels: too small")
    aspx, aspy = params.pixel_aspect_x, params.pixel_aspect_y
    ycor = aspy / aspx
    sensor = params.sensor_height if params.sensor_fit == "VERTICAL" else params.sensor_width
    fit = params.sensor_fit
    if fit == "AUTO":
        fit = "HORIZONTAL" if aspx * width >= aspy * height else "VERTICAL"
    viewfac = float(width) if fit == "HORIZONTAL" else ycor * height
    fx = params.lens * viewfac / sensor
    fy = fx / ycor
    cx = 0.5 * width - params.shift_x * viewfac
    cy = 0.5 * height + params.shift_y * viewfac / ycor

    m = params.matrix_world.copy()
    lengths = np.linalg.norm(m[:3, :3], axis=0)
    if not (lengths > 0).all():
        raise ValueError("matrix_world has a zero-length axis (zero scale)")
    m[:3, :3] /= lengths
    camera_to_world_cv = m @ CAMERA_AXIS_FLIP
    world_to_camera = np.linalg.inv(camera_to_world_cv)
    return Camera(world_to_camera, fx, fy, cx, cy, width, height)


def camera_to_blender(camera: Camera, sensor_width: float = 36.0) -> BlenderCameraParams:
    """Blender settings that render exactly `camera` (the inverse of `camera_from_blender`).

    Chooses sensor_fit 'HORIZONTAL' (so viewfac = W, whatever the aspect), the given
    `sensor_width` (36 mm, full frame), resolution W x H at 100 % (4W x 4H at 25 % when a side
    is below Blender's minimum resolution of 4), and the formulas of `camera_from_blender`
    solved for the rest:

        ycor         = fx / fy;  pixel aspect (1, ycor) if ycor >= 1 else (1 / ycor, 1)
                       (Blender keeps both pixel aspects in [1, 200])
        lens         = fx * sensor_width / W
        shift_x      = (W/2 - cx) / W
        shift_y      = (cy - H/2) * ycor / W
        sensor_height = max(1, sensor_width * (H * aspy) / (W * aspx))   (unused by a
                       horizontal fit; the frame's true height, so that switching the fit to
                       VERTICAL keeps the field of view, unless Blender's 1 mm minimum cuts
                       it; shifts are in units of the fitted side, so they would change)
        matrix_world = inverse(world_to_camera) @ diag(1, -1, -1, 1)

    Blender's lens must be at least 1 mm: for a horizontal field of view wider than that
    allows (fx < W / sensor_width), the lens is set to 1 mm and the sensor widened to W / fx.
    Blender stores these as float32, so a camera set in Blender reproduces `camera` to about
    1e-7 relative; `camera_from_blender(camera_to_blender(c))` reproduces it to rounding.
    """
    width, height = camera.width, camera.height
    if width < 1 or height < 1:
        raise ValueError(f"camera size {width}x{height} is empty")
    ycor = camera.fx / camera.fy
    aspx, aspy = (1.0, ycor) if ycor >= 1.0 else (1.0 / ycor, 1.0)
    if max(aspx, aspy) > 200.0:
        raise ValueError(
            f"fx/fy = {ycor:g} needs a pixel aspect beyond Blender's limit of 200")
    lens = camera.fx * sensor_width / width
    if lens < 1.0:
        lens, sensor_width = 1.0, width / camera.fx
    # Blender's resolution is 4..65536 per axis; smaller images go through the percentage.
    percentage = 100
    if min(width, height) < _MIN_RESOLUTION:
        percentage = 25
    scale = 100 // percentage
    if max(width, height) * scale > _MAX_RESOLUTION:
        raise ValueError(f"camera size {width}x{height} is beyond Blender's resolution limits")
    matrix_world = camera.camera_to_world @ CAMERA_AXIS_FLIP
    return BlenderCameraParams(
        matrix_world=matrix_world,
        lens=lens,
        sensor_width=sensor_width,
        sensor_height=max(1.0, sensor_width * (height * aspy) / (width * aspx)),
        sensor_fit="HORIZONTAL",
        shift_x=(0.5 * width - camera.cx) / width,
        shift_y=(camera.cy - 0.5 * height) * ycor / width,
        resolution_x=width * scale,
        resolution_y=height * scale,
        resolution_percentage=percentage,
        pixel_aspect_x=aspx,
        pixel_aspect_y=aspy,
    )
