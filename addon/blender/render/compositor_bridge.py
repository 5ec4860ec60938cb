"""The compositor bridge: how splats get into every final render Blender makes.

Blender's render pipeline gives Python no hook between the render engine and the compositor,
and no access to the render's pixels. It does, however, render any *other* scene a compositor
Render Layers node points at, with that scene's engine, after the main engine and before the
compositor runs. The bridge uses this:

- a hidden helper scene (`.Splat Composite`) whose render engine is this add-on's
  (`hooks.SplatRenderEngine`); it holds nothing. Blender renders a compositor's scene
  only when it has a camera (4.3 and 5.2 tried: "Cannot render, no camera"), so the helper
  borrows one (`attach_camera`: a pointer to a bridged scene's camera, no object of its own:
  a camera object in the helper scene made Blender 5.2.2 segfault) while the add-on runs;
  files are saved without it (`detach_cameras`, from save_pre), so that a Blender without the
  add-on (a render farm worker that lacks it) fails the render ("no camera") instead of
  writing frames without splats; the add-on attaches it again when a file loads, a scene
  changes or a render starts. The bridged scenes' view layers are saved switched off
  (`switch_off_layers`), so that such a Blender fails at once, not after the scene's meshes;
- in the scene's compositor, a Render Layers node for the helper scene (named "Splat
  Composite"), wired where the scene's own Render Layers "Image", "Alpha" and "Depth" outputs
  were wired (for a scene without a compositor: a new node tree, Render Layers -> Group Output).

When Blender renders the scene (F12, animation, `bpy.ops.render.render`, `blender -b -a/-f`),
the scene's engine (Cycles, EEVEE, Workbench) renders the meshes with a Depth pass; then the
helper's engine runs, reads that render's colour and depth, composes the splats with the native
compositor and returns the composite, which the compositor passes on (through any nodes the user
has after it) to the Render Result, the Image Editor and every file or movie Blender writes.

`ensure_bridge(scene)` sets this up (idempotent) and `remove_bridge(scene)` undoes it, restoring
the links it moved. Blender 5.0 keeps the compositor in `scene.compositing_node_group` (Group
Output node); Blender 4.2-4.5 in `scene.node_tree` (Composite node): both are handled, 5.0 is the
tested one.
"""

from __future__ import annotations

import json

import bpy

from .. import splat_object
from ..blender_splats import data as blender_data

ENGINE_ID = "SPLAT_GAUSSIANS"          # the add-on's RenderEngine (hooks.SplatRenderEngine)
# A leading dot hides the scene from Blender's scene lists; the extension's name in it is what a
# Blender without the extension names in its error ("Engine 'SPLAT_GAUSSIANS' not available for
# scene '.Splat Composite (Gaussian Splatting extension)' (an add-on may need to be installed ...").
HELPER_SCENE = ".Splat Composite (Gaussian Splatting extension)"
HELPER_CAMERA = ".Splat Composite Camera"
HELPER_FLAG = "splat_composite_helper"  # ID property marking the helper scene
LAYERS_FLAG = "splat_layers_off_in_file"  # ID property: view layers switched off in the file
BRIDGE_NODE = "Splat Composite"
BRIDGE_FLAG = "splat_bridge"            # ID property on the bridge node: JSON of what it rewired
TREE_FLAG = "splat_bridge_created"      # ID property on a node tree the bridge created
DEVICE_FLAG = "splat_bridge_device"     # ... and the compositor device it replaced
MOVED_OUTPUTS = ("Image", "Alpha", "Depth")


def uses_node_groups() -> bool:
    """Blender 5.0+: the compositor is a node group in `scene.compositing_node_group`."""
    return "compositing_node_group" in bpy.types.Scene.bl_rna.properties


def is_helper(scene) -> bool:
    return scene is not None and bool(scene.get(HELPER_FLAG, False))


def helper_scene(create: bool = True):
    """The helper scene, created when `create` and missing; its camera attached."""
    scene = next((s for s in bpy.data.scenes if is_helper(s)), None)
    if scene is None:
        if not create:
            return None
        scene = bpy.data.scenes.new(HELPER_SCENE)
        scene[HELPER_FLAG] = True
    if scene.render.engine != ENGINE_ID:
        scene.render.engine = ENGINE_ID
    attach_camera(scene)
    if scene.render.use_compositing:
        scene.render.use_compositing = False
    if scene.render.use_sequencer:
        scene.render.use_sequencer = False
    for view_layer in scene.view_layers:
        if not view_layer.use_pass_z:
            view_layer.use_pass_z = True
    return scene


def _borrowable_camera():
    """A camera for the helper: a bridged scene's, else any scene's (None: no scene has one,
    and then no scene renders anyway)."""
    scenes = [s for s in bpy.data.scenes if not is_helper(s) and s.camera is not None]
    scenes.sort(key=lambda s: bridge_node(s) is None)   # bridged scenes first
    return scenes[0].camera if scenes else None


def attach_camera(helper) -> bool:
    """Give the helper scene a camera if it has none (see the module docstring). Only a
    pointer changes: safe in render_init (tried on 5.2). True if it changed."""
    if helper is None or helper.camera is not None:
        return False
    camera = _borrowable_camera()
    if camera is None:
        return False
    helper.camera = camera
    return True


def detach_cameras() -> None:
    """Before a file is saved: the helpers' borrowed cameras are not saved (see the module
    docstring); `attach_camera` gives them back."""
    for scene in bpy.data.scenes:
        if is_helper(scene) and scene.camera is not None:
            scene.camera = None


def switch_off_layers(scene) -> None:
    """Before a bridged scene is saved: its view layers are saved with Use for Rendering off
    (the names in LAYERS_FLAG). A Blender without the add-on then renders nothing of the scene
    itself and goes straight to the helper scene, which has no camera: the render fails within
    a second, instead of after a whole frame of meshes (Blender renders a compositor's other
    scenes after the scene's own). `switch_on_layers` puts them back (save_post, load_post)."""
    names = [layer.name for layer in scene.view_layers if layer.use]
    if names and scene.library is None:  # a linked scene is its library's to save
        for layer in scene.view_layers:
            layer.use = False
        scene[LAYERS_FLAG] = names


def switch_on_layers(scene) -> None:
    """The view layers `switch_off_layers` switched off for the file, on again."""
    names = scene.get(LAYERS_FLAG)
    if names is None or scene.library is not None:  # linked: read-only, its file's own state
        return
    for name in names:
        layer = scene.view_layers.get(name)
        if layer is not None:
            layer.use = True
    del scene[LAYERS_FLAG]


def tidy_legacy_helpers() -> None:
    """Files saved by earlier versions hold a helper camera object (`.Splat Composite
    Camera`, in the helper scene): it goes, the helper borrows a camera instead; their helper
    scene takes today's name. Not while rendering."""
    for scene in [s for s in bpy.data.scenes if is_helper(s)]:
        if scene.name != HELPER_SCENE and scene.library is None:
            scene.name = HELPER_SCENE
        for obj in list(scene.collection.objects):
            if obj.name.startswith(HELPER_CAMERA) and obj.type == "CAMERA":
                if scene.camera == obj:
                    scene.camera = None
                data = obj.data
                bpy.data.objects.remove(obj)
                if data is not None and data.users == 0:
                    bpy.data.cameras.remove(data)
        attach_camera(scene)


def _collection_has_splats(collection, seen: set, blenders: bool) -> bool:
    if collection is None or collection.session_uid in seen:
        return False
    seen.add(collection.session_uid)
    return any(_object_has_splats(obj, seen, blenders) for obj in collection.all_objects)


def _object_has_splats(obj, seen: set, blenders: bool) -> bool:
    if splat_object.is_splat_object(obj) or (blenders and blender_data.is_blender_splat_object(obj)):
        return True
    if obj.type == "MESH" and splat_object.data_sh_degree(obj.data) is not None:
        return True
    if obj.instance_type == "COLLECTION":
        return _collection_has_splats(obj.instance_collection, seen, blenders)
    return False


def has_splats(scene, *, blenders: bool = True) -> bool:
    """Whether the scene holds splat objects (flagged, or meshes with the splat attributes,
    directly or through collection instances); `blenders=False`: only those Blender cannot show
    without the add-on (not its own splat point clouds). Splats made only by geometry nodes on
    other objects are not seen here: set the bridge up by hand (`ensure_bridge`) for those."""
    seen: set = set()
    return any(_object_has_splats(obj, seen, blenders) for obj in scene.objects)


def _tree(scene, create: bool, layer_name: str | None = None):
    if uses_node_groups():
        tree = scene.compositing_node_group
        if tree is None and create:
            tree = bpy.data.node_groups.new("Splat Composite", "CompositorNodeTree")
            tree[TREE_FLAG] = True
            layers = tree.nodes.new("CompositorNodeRLayers")
            layers.scene = scene
            if layer_name is not None:
                layers.layer = layer_name
            layers.location = (-300, 0)
            output = tree.nodes.new("NodeGroupOutput")
            tree.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
            output.location = (300, 0)
            tree.links.new(layers.outputs["Image"], output.inputs[0])
            scene.compositing_node_group = tree
            _compose_on_cpu(scene, tree)
        return tree
    tree = scene.node_tree  # Blender 4.x
    if create and (tree is None or not scene.use_nodes):
        created = tree is None
        scene.use_nodes = True  # makes the default tree: Render Layers -> Composite
        tree = scene.node_tree
        if created and tree is not None:
            tree[TREE_FLAG] = True
            _compose_on_cpu(scene, tree)
    return tree


def _compose_on_cpu(scene, tree) -> None:
    """A compositor the bridge made only passes the composite through: run it on the CPU, so
    that a machine without a GPU (a render farm, `blender -b`) can render the scene; Blender
    5.2 defaults to the GPU compositor and aborts without one. `remove_bridge` puts the
    device back."""
    if getattr(scene.render, "compositor_device", "CPU") != "CPU":
        tree[DEVICE_FLAG] = scene.render.compositor_device
        scene.render.compositor_device = "CPU"


# Object types Cycles renders as geometry: only these catch shadows. (Blender 5.0 reports
# `is_shadow_catcher` True for every light, which would turn the pass on in any lit scene:
# more Cycles work, a larger render to read, a pass to apply to every frame.)
_GEOMETRY_TYPES = {"MESH", "CURVE", "SURFACE", "META", "FONT", "CURVES", "POINTCLOUD", "VOLUME"}


def has_shadow_catchers(scene) -> bool:
    """Whether the scene holds Cycles shadow catchers (splat proxies, `mesh_convert.make_proxy`,
    or the user's own)."""
    return any(obj.type in _GEOMETRY_TYPES and getattr(obj, "is_shadow_catcher", False)
               for obj in scene.objects)


def needs_shadow_pass(scene, layer) -> bool:
    """Whether the view layer should get Cycles' "Shadow Catcher" pass and does not have it.
    With it, Cycles leaves the catchers out of the Combined pass and the splats are composed
    without them; their shadows are then multiplied over the composite
    (`addon.core.render.composite.apply_shadow_catcher`). Without it a catcher at the depth of the
    splat floor it stands for would hide about half of its shadow behind the floor's own
    Gaussians (those whose centres are nearer than the catcher), and with opaque film it would
    cover the splats behind it with the world colour."""
    cycles = getattr(layer, "cycles", None)  # None until the Cycles add-on is registered
    return (cycles is not None and hasattr(cycles, "use_pass_shadow_catcher")
            and not cycles.use_pass_shadow_catcher and has_shadow_catchers(scene))


def bridge_node(scene):
    tree = _tree(scene, create=False)
    if tree is None:
        return None
    return next((n for n in tree.nodes if n.get(BRIDGE_FLAG) is not None), None)


def uses_depth(scene) -> bool:
    """Whether the scene's compositor reads the bridge node's Depth output (the helper render
    fills its Depth pass only then: 1 ms at 1280x720)."""
    node = bridge_node(scene)
    depth = None if node is None else node.outputs.get("Depth")
    return depth is not None and depth.is_linked


def bridge_view_layer(scene) -> str | None:
    """The view layer the bridge composes the splats with (None when there is no bridge)."""
    node = bridge_node(scene)
    if node is None:
        return None
    return json.loads(node[BRIDGE_FLAG]).get("view_layer")


def _default_view_layer(scene):
    for view_layer in scene.view_layers:
        if view_layer.use:
            return view_layer
    return scene.view_layers[0]


def _is_scene_layers(node, scene, layer: str) -> bool:
    return (node.bl_idname == "CompositorNodeRLayers" and node.get(BRIDGE_FLAG) is None
            and (node.scene is None or node.scene == scene) and node.layer == layer)


def ensure_bridge(scene, view_layer: str | None = None) -> bool:
    """Set the bridge up for `scene` (composing with `view_layer`, by default the one already
    bridged, else the first enabled one). Returns True if anything changed."""
    if is_helper(scene):
        raise ValueError("the splat helper scene cannot be bridged")
    changed = False
    helper = helper_scene()
    node = bridge_node(scene)
    record = json.loads(node[BRIDGE_FLAG]) if node is not None else {"links": []}
    layer_name = view_layer or record.get("view_layer")
    if layer_name is None or layer_name not in scene.view_layers:
        layer_name = _default_view_layer(scene).name
    layer = scene.view_layers[layer_name]
    if not layer.use_pass_z:
        layer.use_pass_z = True
        changed = True
    if needs_shadow_pass(scene, layer):
        layer.cycles.use_pass_shadow_catcher = True
        changed = True
    if not scene.render.use_compositing:
        scene.render.use_compositing = True
        changed = True
    tree = _tree(scene, create=True, layer_name=layer_name)
    if node is None:
        # Made with the helper as the context's scene: a new Render Layers node points at the
        # context's scene, and pointing it elsewhere afterwards leaves the user scene counted
        # twice more (its Scene selector showed "3" after the first import).
        with bpy.context.temp_override(scene=helper):
            node = tree.nodes.new("CompositorNodeRLayers")
        node.name = node.label = BRIDGE_NODE
        node.use_custom_color = True
        node.color = (0.35, 0.45, 0.6)
        changed = True
        scene_layers = [n for n in tree.nodes if _is_scene_layers(n, scene, layer_name)]
        if scene_layers:
            node.location = (scene_layers[0].location.x, scene_layers[0].location.y - 450)
    if node.scene != helper:
        node.scene = helper
        changed = True
    if record.get("view_layer") != layer_name:
        _restore_links(tree, node, record)   # a different view layer: undo the old rewiring
        record = {"links": []}
    record["view_layer"] = layer_name
    # Move every link from the scene's own Render Layers outputs to the bridge node.
    for source in [n for n in tree.nodes if _is_scene_layers(n, scene, layer_name)]:
        for link in list(tree.links):
            if link.from_node != source or link.from_socket.name not in MOVED_OUTPUTS:
                continue
            name, target = link.from_socket.name, link.to_socket
            record["links"].append({"source": source.name, "output": name,
                                    "to_node": link.to_node.name,
                                    "to_socket": target.identifier})
            tree.links.remove(link)
            tree.links.new(node.outputs[name], target)
            changed = True
    if not any(_is_scene_layers(n, scene, layer_name) for n in tree.nodes):
        # The scene must still be rendered: Blender renders a scene for the compositor only
        # when a Render Layers node points at it.
        keep = tree.nodes.new("CompositorNodeRLayers")
        keep.scene = scene
        keep.layer = layer_name
        keep.location = (node.location.x, node.location.y + 450)
        changed = True
    changed |= _feed_unlinked_output(tree, node)
    node[BRIDGE_FLAG] = json.dumps(record)
    return changed


def _feed_unlinked_output(tree, node) -> bool:
    """A compositor whose output gets nothing (its bridge node was deleted, and the links it
    had went with it) gets the bridge's image: what it had before."""
    kinds = ("NodeGroupOutput",) if uses_node_groups() else ("CompositorNodeComposite",)
    for output in [n for n in tree.nodes if n.bl_idname in kinds]:
        if output.inputs and output.inputs[0].type == "RGBA" and not output.inputs[0].is_linked:
            tree.links.new(node.outputs["Image"], output.inputs[0])
            return True
    return False


def _restore_links(tree, node, record: dict) -> None:
    for entry in record.get("links", []):
        source = tree.nodes.get(entry["source"])
        target_node = tree.nodes.get(entry["to_node"])
        if source is None or target_node is None:
            continue
        target = next((s for s in target_node.inputs if s.identifier == entry["to_socket"]), None)
        output = source.outputs.get(entry["output"])
        if target is None or output is None:
            continue
        for link in list(tree.links):
            if link.to_socket == target and link.from_node == node:
                tree.links.remove(link)
        tree.links.new(output, target)


def remove_bridge(scene) -> bool:
    """Undo `ensure_bridge`: links go back to the scene's own Render Layers node, the bridge
    node goes, a node tree the bridge created goes, and the helper scene goes when no scene uses
    it. Returns True if there was a bridge."""
    tree = _tree(scene, create=False)
    node = bridge_node(scene)
    if tree is None or node is None:
        return False
    _restore_links(tree, node, json.loads(node[BRIDGE_FLAG]))
    tree.nodes.remove(node)
    if tree.get(TREE_FLAG):
        if tree.get(DEVICE_FLAG):
            scene.render.compositor_device = tree[DEVICE_FLAG]
        if uses_node_groups():
            scene.compositing_node_group = None
            if tree.users == 0:
                bpy.data.node_groups.remove(tree)
        else:
            scene.use_nodes = False
    if not any(bridge_node(s) is not None for s in bpy.data.scenes if not is_helper(s)):
        helper = next((s for s in bpy.data.scenes if is_helper(s)), None)
        if helper is not None:
            bpy.data.scenes.remove(helper)
    return True


def problems(scene) -> list[str]:
    """Why the bridge would not bring the splats into this scene's final renders (empty when
    it will)."""
    found = []
    node = bridge_node(scene)
    if node is None:
        return ["the compositor bridge is not set up"]
    if not scene.render.use_compositing:
        found.append("compositing is off (Output > Post Processing > Compositing)")
    if node.mute:
        found.append("the Splat Composite node is muted")
    if node.scene is None or not is_helper(node.scene):
        found.append("the Splat Composite node does not point at the helper scene")
    elif node.scene.camera is None:
        found.append("the helper scene has no camera (Blender needs one to render it; the "
                     "scene has none to lend)")
    layer = bridge_view_layer(scene)
    if layer is None or layer not in scene.view_layers:
        found.append(f"view layer {layer!r} is gone")
    elif not scene.view_layers[layer].use_pass_z:
        found.append(f"view layer {layer!r} has no Depth pass")
    elif scene.render.engine == "CYCLES" and needs_shadow_pass(scene, scene.view_layers[layer]):
        found.append(f"view layer {layer!r} has shadow catchers but no Shadow Catcher pass")
    if scene.render.use_sequencer and scene.sequence_editor is not None and \
            len(getattr(scene.sequence_editor, "strips", getattr(scene.sequence_editor, "sequences", []))):
        found.append("the sequencer is on and has strips: Blender skips the compositor")
    return found
