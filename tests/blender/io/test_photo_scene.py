"""A scene made by a COLMAP import renders like the photos: the Standard view transform, and a
World that lights meshes (a converted mesh renders with colour in Cycles from a photo camera)
while camera rays see black, as without one (bpy, the demo COLMAP scene)."""

from __future__ import annotations

from pathlib import Path

import bpy_support as bs
from bpy_support import bpy  # the shared bpy import
import numpy as np
from mathutils import Vector

from addon.blender import mesh_convert, splat_object
from addon.blender.io import photo_scene
from addon.core.images import files
from scenes import sphere_gaussians

DEMO = Path(__file__).resolve().parents[3] / "examples" / "demo_colmap"


def _import(tmp_path, **options):
    bs.reset_scene()
    assert bpy.context.scene.world is None  # an empty scene, as `python -m addon` starts from
    assert bpy.ops.splat.import_colmap(directory=str(DEMO), cache_dir=str(tmp_path / "cache"),
                                       **options) == {"FINISHED"}
    return bpy.context.scene


def test_import_gives_standard_colours_and_a_light_for_meshes(tmp_path):
    scene = _import(tmp_path)
    view = scene.view_settings
    assert (view.view_transform, view.look, view.exposure, view.gamma) == ("Standard", "None",
                                                                           0.0, 1.0)
    assert scene.world is not None and scene.world.name == photo_scene.WORLD_NAME

    scene = _import(tmp_path, photo_colours=False, mesh_light=False)
    assert scene.view_settings.view_transform != "Standard"  # Blender's default (AgX, Filmic)
    assert scene.world is None


def test_a_world_the_scene_has_is_kept(tmp_path):
    bs.reset_scene()
    own = bpy.data.worlds.new("Mine")
    bpy.context.scene.world = own
    assert bpy.ops.splat.import_colmap(directory=str(DEMO),
                                       cache_dir=str(tmp_path / "cache")) == {"FINISHED"}
    assert bpy.context.scene.world == own and len(bpy.data.worlds) == 1


def _render(scene, path: Path) -> np.ndarray:
    scene.render.filepath = str(path)
    scene.render.image_settings.file_format = "PNG"
    bpy.ops.render.render(write_still=True)
    return files.to_float(files.read_pixels(path))[..., :3]


def test_converted_mesh_renders_with_colour_in_cycles(tmp_path):
    """Convert to Mesh in an imported scene, then Cycles from the first photo camera: the mesh
    shows its texture's colours (red above, blue below), the background stays black; without
    the World the mesh is black."""
    scene = _import(tmp_path)
    camera = scene.camera
    forward = camera.matrix_world.to_quaternion() @ Vector((0.0, 0.0, -1.0))
    centre = camera.matrix_world.translation + 4.0 * forward
    obj = splat_object.create_splat_object(sphere_gaussians(0.8, 1500, 0.06), "Ball")
    obj.location = centre
    bpy.context.view_layer.update()
    mesh = mesh_convert.convert_to_mesh(obj, cameras="SPHERE", resolution=24, max_triangles=800,
                                        texture_size=64, view_count=16, view_size=48)
    bpy.data.objects.remove(obj)  # the mesh alone (splats carry their own light)
    assert mesh.name in scene.objects
    scene.render.engine = "CYCLES"
    scene.cycles.samples = 8
    scene.cycles.use_denoising = False
    scene.render.resolution_x, scene.render.resolution_y = 64, 48
    scene.render.resolution_percentage = 100
    scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
    lit = _render(scene, tmp_path / "lit.png")
    h, w = lit.shape[:2]
    middle = lit[h // 3: 2 * h // 3, w // 3: 2 * w // 3]
    corners = np.concatenate([lit[:3, :3], lit[:3, -3:], lit[-3:, :3], lit[-3:, -3:]])
    print(f"mesh middle mean {middle.mean((0, 1))}, corners max {corners.max()}")
    assert middle.mean() > 0.15  # coloured, not black
    assert np.abs(middle[..., 0] - middle[..., 2]).mean() > 0.1  # red and blue, not grey
    assert corners.max() < 0.02  # the camera sees black around it

    scene.world = None
    dark = _render(scene, tmp_path / "dark.png")
    print(f"without the World: mesh middle mean {dark[h // 3: 2 * h // 3, w // 3: 2 * w // 3].mean()}")
    assert dark[h // 3: 2 * h // 3, w // 3: 2 * w // 3].mean() < 0.02
