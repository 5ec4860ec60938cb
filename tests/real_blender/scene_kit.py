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
