"""Scene pieces shared by the bpy tests (tests/blender/render/test_render_with_meshes.py), the
installed-extension stages (scripts/test_installed_extension.py, inside a clean bpy) and the
real-Blender scripts (copied beside them): plain bpy, no imports from this project, since each
runs in its own Python."""

from __future__ import annotations


def material(bpy, name: str, colour, *, emission: bool = True):
    """A material of `colour` (RGB): its viewport colour, and with `emission` an Emission
    shader (Cycles renders it flat, so the expected image needs no lighting)."""
    mat = bpy.data.materials.new(name)
    mat.diffuse_color = (*colour, 1.0)   # Solid shading and Workbench
    if emission:
        if mat.node_tree is None:        # Blender 4.x; 5.x materials always have nodes
            mat.use_nodes = True
        nodes, links = mat.node_tree.nodes, mat.node_tree.links
        nodes.clear()
        node = nodes.new("ShaderNodeEmission")
        node.inputs["Color"].default_value = (*colour, 1.0)
        out = nodes.new("ShaderNodeOutputMaterial")
        links.new(node.outputs[0], out.inputs["Surface"])
    return mat


def multilayer_exr(settings) -> None:
    """Image settings for a 32-bit multilayer EXR (5.0 moved it to `media_type`)."""
    if hasattr(settings, "media_type"):
        settings.media_type = "MULTI_LAYER_IMAGE"
    else:
        settings.file_format = "OPEN_EXR_MULTILAYER"
    settings.color_depth = "32"


def meshes_and_camera(bpy, scene):
    """The real-Blender scenes' meshes and camera: a red cube in front of the splats (about the
    origin), a blue plane behind them, a 35 mm camera 6 units away looking along +Y.
    Returns the camera object."""
    import math
    bpy.ops.mesh.primitive_cube_add(size=0.9, location=(0.35, -2.5, 0.15))
    bpy.context.active_object.data.materials.append(material(bpy, "Cube", (0.9, 0.3, 0.1)))
    bpy.ops.mesh.primitive_plane_add(size=40, location=(0, 2.5, 0), rotation=(math.pi / 2, 0, 0))
    bpy.context.active_object.data.materials.append(material(bpy, "Plane", (0.1, 0.35, 0.8)))
    return camera_in_front(bpy, scene, (0.0, 0.0, 0.0), 6.0 / 2.2)


def flat_cycles(scene, *, samples: int = 4) -> None:
    """Cycles on the CPU, `samples` samples, no denoising, no adaptive sampling, no bounces:
    emission materials render flat, so an expected image needs no lighting."""
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_denoising = False
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.max_bounces = 0


def standard_view(scene) -> None:
    """The Standard view transform, no look, exposure 0, gamma 1, no dither: what written
    files are compared against is computed exactly (tests/standard_view.py)."""
    view = scene.view_settings
    view.view_transform, view.look, view.exposure, view.gamma = "Standard", "None", 0.0, 1.0
    scene.render.dither_intensity = 0.0


def png_8bit(settings) -> None:
    """Image settings for an 8-bit RGBA PNG (5.0 added `media_type`)."""
    if hasattr(settings, "media_type"):
        settings.media_type = "IMAGE"
    settings.file_format, settings.color_mode, settings.color_depth = "PNG", "RGBA", "8"


def render_settings(scene, *, threads: int, frames: tuple[int, int]) -> None:
    """64x48, flat Cycles, `threads` fixed, the Standard view, 8-bit RGBA PNG."""
    scene.render.resolution_x, scene.render.resolution_y = 64, 48
    scene.render.resolution_percentage = 100
    flat_cycles(scene)
    scene.render.threads_mode = "FIXED"
    scene.render.threads = threads
    standard_view(scene)
    scene.frame_start, scene.frame_end = frames
    png_8bit(scene.render.image_settings)


def world_bounds(obj):
    """(low, high, centre, radius) of `obj`'s bounding box in world space (numpy arrays;
    radius is half the box's diagonal)."""
    import numpy as np
    from mathutils import Vector

    corners = np.array([obj.matrix_world @ Vector(c) for c in obj.bound_box])
    low, high = corners.min(axis=0), corners.max(axis=0)
    return low, high, (low + high) / 2, float(np.linalg.norm(high - low)) / 2


def camera_in_front(bpy, scene, centre, radius):
    """A 35 mm camera 2.2 radii before `centre` along -Y, looking along +Y; the scene's
    camera."""
    import math

    camera = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(camera)
    camera.location = (centre[0], centre[1] - 2.2 * radius, centre[2])
    camera.rotation_euler = (math.pi / 2, 0, 0)
    camera.data.lens = 35
    scene.camera = camera
    return camera


# Camera kinds the real-Blender script renders through besides the perspective one, and their
# settings (check.py builds the same camera on the host).
CAMERA_KINDS = {
    "ORTHO": dict(type="ORTHO", ortho_scale=3.2),
    "EQUIRECTANGULAR": dict(type="PANO", panorama_type="EQUIRECTANGULAR"),
    "FISHEYE_EQUISOLID": dict(type="PANO", panorama_type="FISHEYE_EQUISOLID", fisheye_lens=6.0,
                              fisheye_fov=2.7925268),  # 160 degrees
}


def set_camera_kind(cam, kind: str) -> None:
    """Make camera data `cam` one of CAMERA_KINDS (panorama settings on the camera from
    Blender 4.0, on its Cycles settings before)."""
    settings = dict(CAMERA_KINDS[kind])
    cam.type = settings.pop("type")
    target = cam if hasattr(cam, "panorama_type") else cam.cycles
    for key, value in settings.items():
        setattr(cam if key == "ortho_scale" else target, key, value)
