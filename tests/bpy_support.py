"""Shared set-up for the bpy-level splat tests: one bpy import, the add-on registered once, an
empty scene per test, and small helpers (cameras from Blender objects, renders, comparisons)."""

from __future__ import annotations

import bpy  # slow to import: every bpy-level splat test module shares this one import
import numpy as np

import addon
from addon.blender import splat_object
from addon.blender.sources import gather
from addon.core.cameras import BlenderCameraParams, Camera, camera_from_blender
from addon.core.gaussians import Gaussians
from addon.core.render.renderer import render


def ensure_registered() -> None:
    if not hasattr(bpy.types, "SPLAT_OT_import_splats"):
        addon.register()


def reset_scene() -> None:
    """An empty scene (factory settings), the add-on registered, the gather cache empty."""
    ensure_registered()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    ensure_registered()  # registration survives this; checked again to be sure
    gather.clear_cache()


def scene_state() -> tuple:
    """What a failed operator must leave unchanged."""
    return (sorted(o.name for o in bpy.data.objects), sorted(m.name for m in bpy.data.meshes),
            sorted(o.name for o in bpy.context.scene.objects))


def gaussians_equal(a: Gaussians, b: Gaussians) -> bool:
    return all(x.shape == y.shape and np.array_equal(x.view(np.uint32), y.view(np.uint32))
               for x, y in zip(a.arrays().values(), b.arrays().values()))


def add_camera(name: str = "Camera", *, location=(0.0, -6.0, 0.0), rotation=(np.pi / 2, 0, 0),
               lens: float = 35.0, width: int = 64, height: int = 48):
    camera = bpy.data.objects.new(name, bpy.data.cameras.new(name))
    bpy.context.scene.collection.objects.link(camera)
    camera.location = location
    camera.rotation_euler = rotation
    camera.data.lens = lens
    scene = bpy.context.scene
    scene.camera = camera
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    return camera


def splats_and_cube_still(gaussians: Gaussians):
    """A splat object, a cube in front of part of it and a 24x16 camera, rendered by Workbench
    to PNG stills: the scene of the render-failure and helper-data tests."""
    reset_scene()
    scene = bpy.context.scene
    splat_object.create_splat_object(gaussians, "Splats")
    bpy.ops.mesh.primitive_cube_add(size=0.9, location=(0.35, -2.5, 0.15))
    add_camera(location=(0.0, -6.0, 0.0), rotation=(np.pi / 2, 0, 0), width=24, height=16)
    scene.render.engine = "BLENDER_WORKBENCH"
    settings = scene.render.image_settings
    settings.media_type = "IMAGE"
    settings.file_format = "PNG"
    return scene


def camera_of(camera_obj, depsgraph) -> Camera:
    """The camera Blender renders for the evaluated camera object and the scene (perspective,
    orthographic or panoramic)."""
    evaluated = camera_obj.evaluated_get(depsgraph)
    cam, r = evaluated.data, depsgraph.scene.render
    pano = cam if hasattr(cam, "panorama_type") else cam.cycles
    return camera_from_blender(BlenderCameraParams(
        matrix_world=np.array(evaluated.matrix_world, dtype=np.float64), lens=cam.lens,
        sensor_width=cam.sensor_width, sensor_height=cam.sensor_height,
        sensor_fit=cam.sensor_fit, shift_x=cam.shift_x, shift_y=cam.shift_y,
        resolution_x=r.resolution_x, resolution_y=r.resolution_y,
        resolution_percentage=r.resolution_percentage, pixel_aspect_x=r.pixel_aspect_x,
        pixel_aspect_y=r.pixel_aspect_y, type=cam.type, ortho_scale=cam.ortho_scale,
        clip_start=cam.clip_start, clip_end=cam.clip_end, panorama_type=pano.panorama_type,
        fisheye_fov=pano.fisheye_fov, fisheye_lens=pano.fisheye_lens,
        latitude_min=pano.latitude_min, latitude_max=pano.latitude_max,
        longitude_min=pano.longitude_min, longitude_max=pano.longitude_max,
        use_dof=cam.dof.use_dof, aperture_fstop=cam.dof.aperture_fstop,
        focus_distance=cam.dof.focus_distance,
        **{key: getattr(pano, key) for key in _LATER_PANORAMA_KEYS if hasattr(pano, key)}))


# Panorama settings newer Blenders have (the lens polynomial's, the central cylinder's).
_LATER_PANORAMA_KEYS = (*(f"fisheye_polynomial_k{i}" for i in range(5)),
                        *(f"central_cylindrical_range_{a}_{m}" for a in "uv" for m in ("min", "max")),
                        "central_cylindrical_radius")


def render_scene(camera_obj, *, near: float = 0.01, use_cache: bool = True):
    """Gather the scene's splats and render them from `camera_obj` (threads=1: deterministic)."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    result = gather.gather(depsgraph, use_cache=use_cache)
    camera = camera_of(camera_obj, depsgraph)
    return render(result.gaussians, camera, near=near, antialiased=result.antialiased, threads=1)


def mesh_gaussians(obj) -> Gaussians:
    return splat_object.gaussians_from_data(obj.data, drop_hidden=False)
