"""Blender camera objects <-> the core's pinhole `Camera`: the one bpy-side adapter.

The formulas live in `core/cameras.py` (`camera_from_blender`, `camera_to_blender`); this module
only reads those parameters off Blender's datablocks and writes them back, so every operator
that turns a camera object into a `Camera` (render, viewport-free jobs, mesh conversion) or a
`Camera` into a camera object (COLMAP import, scene-to-splats views) goes through here.
"""

from __future__ import annotations

import numpy as np

from ..core.cameras import (
    BlenderCameraParams,
    Camera,
    camera_from_blender,
    camera_near,
    unsupported_camera,
)

# Custom properties that COLMAP import records on a camera object: the photo's own output size,
# percentage and pixel aspect (the scene's render settings hold only one camera's).
RESOLUTION_KEY = "colmap_resolution"
PERCENTAGE_KEY = "colmap_resolution_percentage"
PIXEL_ASPECT_KEY = "colmap_pixel_aspect"
RECORDED_KEYS = (RESOLUTION_KEY, PERCENTAGE_KEY, PIXEL_ASPECT_KEY)


def to_matrix(m: np.ndarray):
    """A numpy (4, 4) as a `mathutils.Matrix` (for `matrix_world` and friends)."""
    import mathutils
    return mathutils.Matrix([list(row) for row in np.asarray(m, np.float64)])


_PANORAMA_KEYS = ("panorama_type", "fisheye_fov", "fisheye_lens", "latitude_min", "latitude_max",
                  "longitude_min", "longitude_max", "fisheye_polynomial_k0",
                  "fisheye_polynomial_k1", "fisheye_polynomial_k2", "fisheye_polynomial_k3",
                  "fisheye_polynomial_k4", "central_cylindrical_range_u_min",
                  "central_cylindrical_range_u_max", "central_cylindrical_range_v_min",
                  "central_cylindrical_range_v_max", "central_cylindrical_radius")


def _panorama_settings(cam) -> dict:
    """The camera data's panorama settings (Blender's own from 4.0 on; Cycles' before)."""
    source = cam if hasattr(cam, "panorama_type") else getattr(cam, "cycles", None)
    if source is None:
        return {}
    return {key: getattr(source, key) for key in _PANORAMA_KEYS if hasattr(source, key)}


def params_of(camera_obj, render, *, use_recorded: bool = False) -> BlenderCameraParams:
    """What Blender renders for a camera object (perspective, orthographic or panoramic) with
    the scene's `render` settings; with `use_recorded`, the camera's own COLMAP resolution,
    percentage and pixel aspect where it has them (see `record_output_settings`)."""
    res = (render.resolution_x, render.resolution_y)
    percentage = render.resolution_percentage
    aspect = (render.pixel_aspect_x, render.pixel_aspect_y)
    if use_recorded:
        res = tuple(camera_obj.get(RESOLUTION_KEY, res))
        percentage = camera_obj.get(PERCENTAGE_KEY, percentage)
        aspect = tuple(camera_obj.get(PIXEL_ASPECT_KEY, aspect))
    cam = camera_obj.data
    return BlenderCameraParams(
        matrix_world=np.array(camera_obj.matrix_world, dtype=np.float64), lens=cam.lens,
        sensor_width=cam.sensor_width, sensor_height=cam.sensor_height,
        sensor_fit=cam.sensor_fit, shift_x=cam.shift_x, shift_y=cam.shift_y,
        resolution_x=int(res[0]), resolution_y=int(res[1]),
        resolution_percentage=int(percentage),
        pixel_aspect_x=float(aspect[0]), pixel_aspect_y=float(aspect[1]),
        type=cam.type if cam.type in ("PERSP", "ORTHO", "PANO") else "PERSP",
        ortho_scale=cam.ortho_scale, clip_start=cam.clip_start, clip_end=cam.clip_end,
        use_dof=bool(cam.dof.use_dof), aperture_fstop=cam.dof.aperture_fstop,
        focus_distance=focus_distance(camera_obj), **_panorama_settings(cam))


def focus_distance(camera_obj) -> float:
    """The camera's focus distance: its focus object's distance along the view axis where it
    has one (as Cycles' `blender_camera_focal_distance`, bones aside), else Focus Distance."""
    dof = camera_obj.data.dof
    target = dof.focus_object
    if target is None:
        return float(dof.focus_distance)
    m = np.array(camera_obj.matrix_world, np.float64)
    axis = m[:3, 2] / np.linalg.norm(m[:3, 2])
    offset = m[:3, 3] - np.array(target.matrix_world, np.float64)[:3, 3]
    return float(abs(axis @ offset))


def camera_of(camera_obj, render, *, use_recorded: bool = False) -> Camera:
    """The `Camera` Blender renders for a camera object (any type `render_problem` allows)."""
    return camera_from_blender(params_of(camera_obj, render, use_recorded=use_recorded))


# Engines that render panoramic cameras as panoramas (EEVEE and Workbench draw them as
# perspective views, which splats drawn as a panorama would not match).
PANORAMA_ENGINES = ("CYCLES",)


def render_problem(camera_obj, engine: str | None = None) -> str | None:
    """Why splats cannot be rendered through `camera_obj` (an object the scene renders with)
    by the render engine `engine` (None: any that can), or None when they can."""
    if camera_obj is None:
        return None
    if camera_obj.type != "CAMERA":
        return (f"the scene renders through {camera_obj.name!r}, a {camera_obj.type.lower()} "
                "object: splats render through camera objects only")
    cam = camera_obj.data
    if cam.type not in ("PERSP", "ORTHO", "PANO"):
        return (f"camera {camera_obj.name!r} is a {cam.type.lower()} camera: splats render "
                "through perspective, orthographic and panoramic cameras")
    if cam.type == "PANO":
        settings = _panorama_settings(cam)
        kind = settings.get("panorama_type", "")
        probe = BlenderCameraParams(np.eye(4), 50.0, 36.0, 24.0, "AUTO", 0.0, 0.0, 4, 4,
                                    type="PANO", panorama_type=kind,
                                    use_dof=bool(cam.dof.use_dof))
        reason = unsupported_camera(probe)
        if reason:
            return f"camera {camera_obj.name!r}: {reason}"
        if engine is not None and engine not in PANORAMA_ENGINES:
            return (f"camera {camera_obj.name!r} is panoramic, which the {engine} engine renders "
                    "as a perspective view: render it with Cycles (or the splats alone)")
    return None


def near_of(camera_obj, near: float) -> float:
    """The near plane a render through `camera_obj` uses, given the splat render setting."""
    cam = camera_obj.data
    return camera_near(BlenderCameraParams(np.eye(4), 50.0, 36.0, 24.0, "AUTO", 0.0, 0.0, 4, 4,
                                           type=cam.type, clip_start=cam.clip_start), near)


def frame_size(render) -> tuple[int, int]:
    """The full frame in pixels (resolution x percentage, truncated as Blender does)."""
    return (render.resolution_x * render.resolution_percentage // 100,
            render.resolution_y * render.resolution_percentage // 100)


def set_lens(cam, params: BlenderCameraParams) -> None:
    """Write the intrinsics of `params` into camera data `cam` (a perspective camera)."""
    cam.type = "PERSP"
    cam.sensor_fit = params.sensor_fit
    cam.sensor_width = params.sensor_width
    cam.sensor_height = params.sensor_height
    cam.lens = params.lens
    cam.shift_x = params.shift_x
    cam.shift_y = params.shift_y


def set_camera(camera_obj, params: BlenderCameraParams) -> None:
    """Place a camera object and set its lens so that it renders `params`' view.

    The pose is kept as a quaternion: Blender stores an object's rotation in its rotation mode,
    in float32, and an Euler decomposition near gimbal lock loses digits (a COLMAP view looking
    almost along world X came back 0.13 px off at 2354x1007 with Euler XYZ)."""
    set_lens(camera_obj.data, params)
    camera_obj.rotation_mode = "QUATERNION"
    camera_obj.matrix_world = to_matrix(params.matrix_world)


def record_output_settings(camera_obj, params: BlenderCameraParams) -> None:
    """Remember `params`' output size, percentage and pixel aspect on the camera object."""
    camera_obj[RESOLUTION_KEY] = (params.resolution_x, params.resolution_y)
    camera_obj[PERCENTAGE_KEY] = params.resolution_percentage
    camera_obj[PIXEL_ASPECT_KEY] = (params.pixel_aspect_x, params.pixel_aspect_y)


def has_recorded_output(camera_obj) -> bool:
    return camera_obj is not None and all(key in camera_obj for key in RECORDED_KEYS)


def marker_camera(scene, frame: int):
    """The camera Blender's markers bind at `frame` (the last marker at or before it, else the
    first one; markers whose camera is hidden from renders do not count), or None without such
    markers: Blender's own rule (BKE_scene_camera_switch_find), which it applies only when a
    frame is evaluated, after render-start handlers run."""
    best = first = None
    for marker in scene.timeline_markers:
        camera = marker.camera
        if camera is None or camera.hide_render:
            continue
        if marker.frame <= frame and (best is None or marker.frame > best.frame):
            best = marker
        if first is None or marker.frame < first.frame:
            first = marker
    chosen = best or first
    return chosen.camera if chosen is not None else None


def recorded_output(camera_obj) -> tuple[int, int, int, float, float] | None:
    """(width, height, percentage, pixel aspect x, y) recorded on a camera, or None."""
    if not has_recorded_output(camera_obj):
        return None
    width, height = (int(v) for v in camera_obj[RESOLUTION_KEY])
    aspect_x, aspect_y = (float(v) for v in camera_obj[PIXEL_ASPECT_KEY])
    return width, height, int(camera_obj[PERCENTAGE_KEY]), aspect_x, aspect_y


def apply_recorded_output(render, camera_obj) -> bool:
    """Set the scene's output size, percentage and pixel aspect from the camera's recorded
    ones. False (nothing changed) when the camera has none. Writes only what differs, so an
    unchanged scene is not tagged for a redraw."""
    if not has_recorded_output(camera_obj):
        return False
    width, height = (int(v) for v in camera_obj[RESOLUTION_KEY])
    percentage = int(camera_obj[PERCENTAGE_KEY])
    aspect_x, aspect_y = (float(v) for v in camera_obj[PIXEL_ASPECT_KEY])
    if (render.resolution_x, render.resolution_y) != (width, height):
        render.resolution_x, render.resolution_y = width, height
    if render.resolution_percentage != percentage:
        render.resolution_percentage = percentage
    stored = np.float32((render.pixel_aspect_x, render.pixel_aspect_y))  # Blender keeps float32
    if not np.array_equal(stored, np.float32((aspect_x, aspect_y))):
        render.pixel_aspect_x, render.pixel_aspect_y = aspect_x, aspect_y
    return True
