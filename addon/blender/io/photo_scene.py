"""What a scene made from photos gets so that it renders like them: the look and the light.

- The look (`use_photo_colours`): the add-on draws and composes splats in display sRGB, the
  photos' own encoding, which the "Standard" view transform shows unchanged. Blender's default,
  AgX, tone-maps them: washed out, further from the photos (issue 27 measured the walkthrough's
  camera 008 at 20.2 dB under AgX against 23.2 dB under Standard). A COLMAP import sets Standard
  (look None, exposure 0, gamma 1) on its scene by default (its "Photo Colours" option).
- The light (`add_mesh_light`): splats carry their own light, meshes do not; a scene without a
  World renders them black. A COLMAP import into a scene without a World gives it one (its
  "Light for Meshes" option): a uniform white light of strength 1 for every ray but camera rays,
  which see black, as they do without a World. A diffuse mesh textured from the splats (Convert
  to Mesh) then renders about its texture's colours (a Lambertian surface under a uniform unit
  light reflects its albedo, less where it is occluded), and the frame's background is unchanged.
  A World the scene already has is left alone.
"""

from __future__ import annotations

import bpy

STANDARD = "Standard"
WORLD_NAME = "Light for Meshes"


def use_photo_colours(scene) -> bool:
    """The Standard view transform, no look, exposure 0, gamma 1. True if anything changed."""
    view = scene.view_settings
    before = (view.view_transform, view.look, view.exposure, view.gamma)
    view.view_transform = STANDARD
    view.look = "None"
    view.exposure = 0.0
    view.gamma = 1.0
    return before != (view.view_transform, view.look, view.exposure, view.gamma)


def add_mesh_light(scene) -> bpy.types.World | None:
    """A World lighting meshes (see the module notes) for a scene that has none; None when the
    scene has one (it is the user's)."""
    if scene.world is not None:
        return None
    world = bpy.data.worlds.new(WORLD_NAME)
    try:
        world.color = (0.0, 0.0, 0.0)  # what the "splats only" engine reads as the background
        if bpy.app.version < (5, 0, 0):  # always node based from 5.0
            world.use_nodes = True
        nodes, links = world.node_tree.nodes, world.node_tree.links
        background = next((n for n in nodes if n.type == "BACKGROUND"), None) \
            or nodes.new("ShaderNodeBackground")
        output = next((n for n in nodes if n.type == "OUTPUT_WORLD"), None) \
            or nodes.new("ShaderNodeOutputWorld")
        path = nodes.new("ShaderNodeLightPath")
        mix = nodes.new("ShaderNodeMix")
        mix.data_type = "RGBA"
        mix.inputs[6].default_value = (1.0, 1.0, 1.0, 1.0)   # A: the light
        mix.inputs[7].default_value = (0.0, 0.0, 0.0, 1.0)   # B: what the camera sees
        links.new(path.outputs["Is Camera Ray"], mix.inputs["Factor"])
        links.new(mix.outputs[2], background.inputs["Color"])
        background.inputs["Strength"].default_value = 1.0
        links.new(background.outputs["Background"], output.inputs["Surface"])
        path.location, mix.location = (-500, 200), (-250, 200)
        scene.world = world
    except BaseException:
        bpy.data.worlds.remove(world)
        raise
    return world
