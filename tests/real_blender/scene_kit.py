"""Scene pieces shared by the bpy tests (tests/blender/render/test_render_with_meshes.py), the installed-extension
driver (scripts/test_installed_extension.py, inside a clean bpy venv) and the real-Blender scripts
(copied beside them): plain bpy, no imports from this project, since each runs in its own Python."""

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
