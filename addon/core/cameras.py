"""Cameras in the COLMAP/OpenCV convention (x right, y down, z forward): pinhole, orthographic
and panoramic (docs/conventions.md, "Cameras beyond the pinhole").

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

# Projection models, with the native code of each (native/include/splatcore.h, sc_model) and
# how many parameters `Camera.params` holds for it. Pinhole and orthographic need none (fx, fy,
# cx, cy say it all); a panorama maps a camera-space direction to Cycles' normalised (u, v)
# (v up), and then to pixels as col = fx u + cx, row = cy - fy v.
MODELS = {"PINHOLE": (0, 0), "ORTHO": (1, 0), "EQUIRECTANGULAR": (2, 4),
          "FISHEYE_EQUIDISTANT": (3, 1), "FISHEYE_EQUISOLID": (4, 4), "MIRRORBALL": (5, 0),
          "FISHEYE_LENS_POLYNOMIAL": (6, 8), "EQUIANGULAR_CUBEMAP_FACE": (7, 0),
          "CENTRAL_CYLINDRICAL": (8, 4)}
PANORAMAS = tuple(name for name, (code, _) in MODELS.items() if code >= 2)
CAMERA_TYPES = ("PERSP", "ORTHO", "PANO")  # Blender's camera types that splats render through
PANORAMA_TYPES = PANORAMAS  # Blender's panorama types that splats render through (named alike)
MAX_MODEL_PARAMS = 10  # the native intrinsics vector: fx fy cx cy model far p0..p9


@dataclass
class Camera:
    """A camera: pose, intrinsics, image size and projection model.

    PINHOLE: (fx x/z + cx, fy y/z + cy).  ORTHO: (fx x + cx, fy y + cy), fx and fy in pixels per
    world unit; every Gaussian is seen along the view axis.  Panoramas (`PANORAMAS`): the
    camera-space direction mapped to Cycles' (u, v) by the model (with `params`), then
    (fx u + cx, cy - fy v); depth is the distance from the camera centre, not z.
    `far`: Gaussians deeper than this are culled (a camera's clip_end; inf for none).
    `aperture`, `focus`: depth of field (PINHOLE and ORTHO; aperture 0: none), a thin lens of
    that radius in world units focused at view depth `focus` (docs/conventions.md).
    """

    world_to_camera: np.ndarray  # (4, 4) float64, rigid
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    model: str = "PINHOLE"
    params: tuple[float, ...] = ()
    far: float = float("inf")
    aperture: float = 0.0
    focus: float = 1.0

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
        if self.model not in MODELS:
            raise ValueError(f"camera model must be one of {tuple(MODELS)}, got {self.model!r}")
        self.params = tuple(float(v) for v in self.params)
        if len(self.params) != MODELS[self.model][1] or not np.isfinite(self.params).all():
            raise ValueError(f"a {self.model} camera takes {MODELS[self.model][1]} finite "
                             f"parameters, got {self.params}")
        self.far = float(self.far)
        if np.isnan(self.far):
            raise ValueError("far must not be NaN")
        self.aperture, self.focus = float(self.aperture), float(self.focus)
        if not (np.isfinite(self.aperture) and self.aperture >= 0 and np.isfinite(self.focus)
                and self.focus > 0):
            raise ValueError(f"depth of field needs aperture >= 0 and focus > 0, got "
                             f"{self.aperture}, {self.focus}")
        if self.aperture > 0 and self.model not in ("PINHOLE", "ORTHO"):
            raise ValueError("depth of field is drawn through pinhole and orthographic cameras only")

    @property
    def is_pinhole(self) -> bool:
        return self.model == "PINHOLE"

    @property
    def forward(self) -> np.ndarray:
        """The world direction the camera looks along (its +z axis)."""
        return self.world_to_camera[2, :3] / np.linalg.norm(self.world_to_camera[2, :3])

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

    Perspective, orthographic and panoramic cameras (`type` 'PERSP' | 'ORTHO' | 'PANO', with
    `panorama_type` one of `PANORAMA_TYPES`). Mono views only: stereo 3D's extra interocular
    shift is not modelled, nor are border crop and viewport zoom/offset.

    matrix_world: (4, 4) camera-to-world of the camera object, Blender camera frame (looks down
        its local -Z, +Y up in the image). It may carry scale (also negative or from a parent);
        Blender normalises the three axes before inverting it for the view, and so do we.
    lens: focal length in mm. sensor_width, sensor_height: in mm.
    sensor_fit: 'AUTO' | 'HORIZONTAL' | 'VERTICAL'.
    shift_x, shift_y: lens shift in units of the fitted sensor size.
    resolution_x, resolution_y, resolution_percentage: the scene's output size; the rendered
        image is `resolution * percentage // 100` pixels (integer truncation, as Blender does).
    pixel_aspect_x, pixel_aspect_y: Blender keeps both in [1, 200].
    type: 'PERSP' | 'ORTHO' | 'PANO'; ortho_scale: the fitted side's extent in world units;
    clip_start, clip_end: the camera's clipping (orthographic and panoramic renders cull
    Gaussians beyond clip_end; clip_start is the render's near plane, see `camera_near`).
    panorama_type, fisheye_fov, fisheye_lens, latitude_min/max, longitude_min/max,
    fisheye_polynomial_k0..k4, central_cylindrical_range_u_min/max (longitude, radians),
    central_cylindrical_range_v_min/max (height), central_cylindrical_radius: Blender's panorama
    settings (radians, mm, scene units).
    use_dof, aperture_fstop, focus_distance: the camera's depth of field (the focus distance
    along the view axis, a focus object's already resolved: `camera_adapter`).
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
    type: str = "PERSP"
    ortho_scale: float = 6.0
    clip_start: float = 0.1
    clip_end: float = 1000.0
    panorama_type: str = "FISHEYE_EQUISOLID"
    fisheye_fov: float = np.pi
    fisheye_lens: float = 10.5
    latitude_min: float = -np.pi / 2
    latitude_max: float = np.pi / 2
    longitude_min: float = -np.pi
    longitude_max: float = np.pi
    fisheye_polynomial_k0: float = -1.1735143743862864e-05   # Blender's defaults
    fisheye_polynomial_k1: float = -0.019988736137747765
    fisheye_polynomial_k2: float = -3.3525323033245513e-06
    fisheye_polynomial_k3: float = 3.0992753181635635e-06
    fisheye_polynomial_k4: float = -2.60646473293491e-08
    central_cylindrical_range_u_min: float = -np.pi
    central_cylindrical_range_u_max: float = np.pi
    central_cylindrical_range_v_min: float = -1.0
    central_cylindrical_range_v_max: float = 1.0
    central_cylindrical_radius: float = 1.0
    use_dof: bool = False
    aperture_fstop: float = 2.8
    focus_distance: float = 10.0

    def __post_init__(self) -> None:
        m = np.array(self.matrix_world, dtype=np.float64)
        if m.shape != (4, 4):
            raise ValueError(f"matrix_world must be 4x4, got shape {m.shape}")
        self.matrix_world = m
        for name in ("lens", "sensor_width", "sensor_height", "shift_x", "shift_y",
                     "pixel_aspect_x", "pixel_aspect_y", "ortho_scale", "clip_start", "clip_end",
                     "fisheye_fov", "fisheye_lens", "latitude_min", "latitude_max",
                     "longitude_min", "longitude_max", "aperture_fstop", "focus_distance",
                     "fisheye_polynomial_k0", "fisheye_polynomial_k1", "fisheye_polynomial_k2",
                     "fisheye_polynomial_k3", "fisheye_polynomial_k4",
                     "central_cylindrical_range_u_min", "central_cylindrical_range_u_max",
                     "central_cylindrical_range_v_min", "central_cylindrical_range_v_max",
                     "central_cylindrical_radius"):
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
        if self.type not in CAMERA_TYPES:
            raise ValueError(f"camera type must be one of {CAMERA_TYPES}, got {self.type!r}")
        for name in ("lens", "sensor_width", "sensor_height", "pixel_aspect_x", "pixel_aspect_y",
                     "ortho_scale", "fisheye_fov", "fisheye_lens", "central_cylindrical_radius"):
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


def unsupported_camera(params: BlenderCameraParams) -> str | None:
    """Why splats cannot be rendered through this camera, or None when they can."""
    if params.type == "PANO" and params.use_dof:
        return ("depth of field through a panoramic camera is not supported (splats render "
                "with it through perspective and orthographic cameras): turn it off")
    if params.type == "PANO" and params.panorama_type not in PANORAMA_TYPES:
        return (f"the {params.panorama_type.replace('_', ' ').lower()} panorama is not supported "
                f"(splats render through {', '.join(PANORAMA_TYPES).replace('_', ' ').lower()} "
                "panoramas, perspective and orthographic cameras)")
    return None


def camera_near(params: BlenderCameraParams, near: float) -> float:
    """The near plane a render of `params` uses, given the render's own `near` (the splat render
    setting): pinhole cameras keep it (the camera's clip_start does not cull splats, as before);
    orthographic and panoramic ones clip at their clip_start as Cycles does, and at `near` too
    where that is larger."""
    return near if params.type == "PERSP" else max(near, params.clip_start)


def camera_from_blender(params: BlenderCameraParams) -> Camera:
    """The `Camera` that renders exactly what Blender renders for `params`: perspective,
    orthographic or panoramic (`_special_camera_from_blender` for the last two).

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
    if params.type != "PERSP":
        return _special_camera_from_blender(params, width, height)
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

    aperture, focus = depth_of_field(params)
    return Camera(_world_to_camera(params), fx, fy, cx, cy, width, height, aperture=aperture,
                  focus=focus)


def depth_of_field(params: BlenderCameraParams) -> tuple[float, float]:
    """(aperture radius in world units, focus distance) of Cycles' thin lens for `params`
    (`blender_camera_from_object`): lens (mm, as metres) / (2 f-stop) for a perspective camera,
    1 / (2 f-stop) for an orthographic one, f-stop at least 1e-5; (0, 1) without depth of field.
    The aperture's blades and anamorphic ratio are not modelled (a round aperture)."""
    if not params.use_dof or params.type == "PANO":
        return 0.0, 1.0
    fstop = max(params.aperture_fstop, 1e-5)
    aperture = (1.0 if params.type == "ORTHO" else params.lens * 1e-3) / (2.0 * fstop)
    return aperture, max(params.focus_distance, 1e-6)


def _world_to_camera(params: BlenderCameraParams) -> np.ndarray:
    m = params.matrix_world.copy()
    lengths = np.linalg.norm(m[:3, :3], axis=0)
    if not (lengths > 0).all():
        raise ValueError("matrix_world has a zero-length axis (zero scale)")
    m[:3, :3] /= lengths
    return np.linalg.inv(m @ CAMERA_AXIS_FLIP)


def _special_camera_from_blender(params: BlenderCameraParams, width: int, height: int) -> Camera:
    """Orthographic and panoramic cameras (docs/conventions.md, "Cameras beyond the pinhole").

    ORTHO, from Blender's `BKE_camera_params_compute_viewplane` with `pixsize = ortho_scale /
    viewfac`: the perspective formulas with lens / sensor replaced by 1 / ortho_scale,

        fx = viewfac / ortho_scale,  fy = fx / ycor,  cx, cy as for a perspective camera,

    so pixel = (fx x + cx, fy y + cy) in the camera frame; depth z.

    PANO, from Cycles' `blender_camera_viewplane` (the viewplane is the unit square moved by
    the shift) and its sensor for equisolid fisheyes (the fitted sensor side, the other side
    from the render's aspect; AUTO fits horizontally when W aspx > H aspy):

        u = col / W + shift_x,  v = row_from_bottom / H + shift_y
        ->  fx = W, cx = -shift_x W, fy = H, cy = H (1 + shift_y)

    and the model's parameters: EQUIRECTANGULAR (longitude min, max, latitude min, max),
    FISHEYE_EQUIDISTANT (fov), FISHEYE_EQUISOLID (lens, fov, sensor width, sensor height),
    MIRRORBALL (none), FISHEYE_LENS_POLYNOMIAL (k0..k4, fov, sensor width, sensor height),
    EQUIANGULAR_CUBEMAP_FACE (none), CENTRAL_CYLINDRICAL (longitude min, max, height min / radius,
    height max / radius: Cycles' own division, so the heights are on a unit cylinder).
    Both cull beyond clip_end.
    """
    world_to_camera = _world_to_camera(params)
    aspx, aspy = params.pixel_aspect_x, params.pixel_aspect_y
    if params.type == "ORTHO":
        ycor = aspy / aspx
        fit = params.sensor_fit
        if fit == "AUTO":
            fit = "HORIZONTAL" if aspx * width >= aspy * height else "VERTICAL"
        viewfac = float(width) if fit == "HORIZONTAL" else ycor * height
        fx = viewfac / params.ortho_scale
        aperture, focus = depth_of_field(params)
        return Camera(world_to_camera, fx, fx / ycor, 0.5 * width - params.shift_x * viewfac,
                      0.5 * height + params.shift_y * viewfac / ycor, width, height,
                      model="ORTHO", far=params.clip_end, aperture=aperture, focus=focus)
    reason = unsupported_camera(params)
    if reason:
        raise ValueError(reason)
    kind = params.panorama_type
    if kind == "EQUIRECTANGULAR":
        model_params = (params.longitude_min, params.longitude_max, params.latitude_min,
                        params.latitude_max)
        if not (model_params[1] > model_params[0] and model_params[3] > model_params[2]):
            raise ValueError("the equirectangular camera's latitude or longitude range is empty")
    elif kind == "CENTRAL_CYLINDRICAL":
        radius = params.central_cylindrical_radius
        model_params = (params.central_cylindrical_range_u_min,
                        params.central_cylindrical_range_u_max,
                        params.central_cylindrical_range_v_min / radius,
                        params.central_cylindrical_range_v_max / radius)
        if not (model_params[1] > model_params[0] and model_params[3] > model_params[2]):
            raise ValueError("the central cylindrical camera's longitude or height range is empty")
    elif kind == "FISHEYE_EQUIDISTANT":
        model_params = (params.fisheye_fov,)
    elif kind in ("FISHEYE_EQUISOLID", "FISHEYE_LENS_POLYNOMIAL"):
        x_ratio, y_ratio = width * aspx, height * aspy
        horizontal = params.sensor_fit == "HORIZONTAL" or (
            params.sensor_fit == "AUTO" and x_ratio > y_ratio)
        size = params.sensor_height if params.sensor_fit == "VERTICAL" else params.sensor_width
        sensor = (size, size * y_ratio / x_ratio) if horizontal else (size * x_ratio / y_ratio, size)
        model_params = (params.fisheye_lens, params.fisheye_fov, *sensor)
        if kind == "FISHEYE_LENS_POLYNOMIAL":
            model_params = (*(getattr(params, f"fisheye_polynomial_k{i}") for i in range(5)),
                            params.fisheye_fov, *sensor)
    else:
        model_params = ()
    return Camera(world_to_camera, float(width), float(height), -params.shift_x * width,
                  height * (1.0 + params.shift_y), width, height, model=kind,
                  params=model_params, far=params.clip_end)


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
    if not camera.is_pinhole:
        raise ValueError(f"only pinhole cameras become Blender settings, not {camera.model}")
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


def image_coverage(camera: Camera) -> np.ndarray | None:
    """Which pixels a panorama shows anything at (H, W) bool, as Cycles' `*_to_direction`
    decide (outside a fisheye's or the mirror ball's image circle it traces no ray); None when
    every pixel does (pinhole, orthographic, equirectangular). Splats are not drawn where the
    camera shows nothing: there the render keeps Blender's own pixel."""
    if camera.model not in ("FISHEYE_EQUIDISTANT", "FISHEYE_EQUISOLID", "MIRRORBALL",
                            "FISHEYE_LENS_POLYNOMIAL"):
        return None
    cols = (np.arange(camera.width) + 0.5 - camera.cx) / camera.fx
    rows = (camera.cy - np.arange(camera.height) - 0.5) / camera.fy
    u, v = np.meshgrid(cols, rows)
    if camera.model == "FISHEYE_EQUIDISTANT":
        return (2 * u - 1) ** 2 + (2 * v - 1) ** 2 <= 1.0
    if camera.model == "MIRRORBALL":
        return (2 * u - 1) ** 2 + (2 * v - 1) ** 2 <= 1.0
    if camera.model == "FISHEYE_LENS_POLYNOMIAL":  # |theta| <= fov / 2, theta = -p(r)
        *k, fov, sensor_w, sensor_h = camera.params
        r = np.hypot((u - 0.5) * sensor_w, (v - 0.5) * sensor_h)
        theta = -(k[0] + r * (k[1] + r * (k[2] + r * (k[3] + r * k[4]))))
        return np.abs(theta) <= 0.5 * fov
    lens, fov, sensor_w, sensor_h = camera.params
    radius = np.hypot((u - 0.5) * sensor_w, (v - 0.5) * sensor_h)
    return radius <= min(2 * lens * np.sin(fov / 4), 2 * lens)
