"""The compositor bridge's helper data heals itself and stays out of the user's way (bpy).

Each piece the bridge needs is taken away in turn, as scripts and users do (a generation script
emptying `bpy.data.objects`, the helper scene deleted or renamed, the Splat Composite node
deleted or renamed), then F12 renders: the frame must equal the one rendered before, splats
included. And: the user's scene is not counted as used more often than a plain compositor
makes it, no helper object is in `bpy.data.objects`, files are saved without the helper's
borrowed camera (so a Blender without the add-on refuses to render them; see
`compositor_bridge`), and files from earlier versions lose their helper camera object on load.
The same in real Blender 5.2, where a render cannot repair the bridge, is in scripts/test_farm.py.
"""

from __future__ import annotations


import bpy_support as bs
from bpy_support import bpy  # the shared bpy import
import numpy as np
import pytest

from addon.blender import splat_object
from addon.blender.render import compositor_bridge as bridge, failures
from scenes import random_gaussians
from standard_view import read_png


def _scene(rng):
    scene = bs.splats_and_cube_still(random_gaussians(rng, 200, 1, radius=1.0))
    scene.render.image_settings.color_mode = "RGBA"
    scene.render.dither_intensity = 0.0
    bridge.ensure_bridge(scene)
    return scene


def _render(scene, path) -> np.ndarray:
    scene.render.filepath = str(path)
    assert bpy.ops.render.render(write_still=True) == {"FINISHED"}, failures.last_errors()
    assert failures.last_errors() == []
    return read_png(str(path) + ".png")


def _without_splats(scene, path) -> np.ndarray:
    scene.splat_render.enabled = False
    try:
        return _render(scene, path)
    finally:
        scene.splat_render.enabled = True


def _delete_objects(scene):
    """A script's first line, after the scene was set up: every object goes (the user's too),
    then the script builds its scene again."""
    camera = scene.camera
    state = (camera.location.copy(), camera.rotation_euler.copy())
    names = [o.name for o in scene.objects]
    keep = {o.name: o.copy() for o in scene.objects}  # copies, not linked anywhere yet
    for obj in list(bpy.data.objects):
        if obj.name in names:
            bpy.data.objects.remove(obj)
    for name, obj in keep.items():
        obj.name = name
        scene.collection.objects.link(obj)
        if obj.type == "CAMERA":
            scene.camera = obj
            obj.location, obj.rotation_euler = state


def _delete_helper_scene(scene):
    bpy.data.scenes.remove(bridge.helper_scene(create=False))


def _rename_helper_scene(scene):
    bridge.helper_scene(create=False).name = "Renamed by a script"


def _delete_bridge_node(scene):
    tree = scene.compositing_node_group
    tree.nodes.remove(bridge.bridge_node(scene))


def _rename_bridge_node(scene):
    node = bridge.bridge_node(scene)
    node.name = node.label = "Something else"


def _clear_helper_camera(scene):
    bridge.helper_scene(create=False).camera = None


@pytest.mark.parametrize("damage", [_delete_objects, _delete_helper_scene, _rename_helper_scene,
                                    _delete_bridge_node, _rename_bridge_node,
                                    _clear_helper_camera])
def test_the_render_repairs_what_was_taken(rng, tmp_path, damage):
    scene = _scene(rng)
    before = _render(scene, tmp_path / "before")
    plain = _without_splats(scene, tmp_path / "plain")
    assert np.abs(before - plain).max() > 40, "the splats did not show in the first place"
    damage(scene)
    after = _render(scene, tmp_path / "after")
    assert np.abs(after - before).max() <= 1
    node = bridge.bridge_node(scene)
    assert node is not None and bridge.is_helper(node.scene) and bridge.problems(scene) == []
    assert node.scene.camera is not None   # Blender 5.1+ refuses a compositor scene without one


def test_the_helpers_stay_out_of_the_users_way(rng):
    bs.reset_scene()
    scene = bpy.context.scene
    plain = bpy.data.node_groups.new("Plain", "CompositorNodeTree")
    plain.nodes.new("CompositorNodeRLayers")       # what a user's own compositor costs
    users_with_a_compositor = scene.users
    bpy.data.node_groups.remove(plain)
    scene = _scene(rng)
    assert scene.users == users_with_a_compositor
    assert not [o.name for o in bpy.data.objects if o.name.startswith(".")]
    helper = bridge.helper_scene(create=False)
    assert helper.name.startswith(".") and len(helper.objects) == 0
    assert helper.camera == scene.camera     # borrowed: a pointer, no user, no object


def test_files_are_saved_without_the_borrowed_camera(rng, tmp_path):
    scene = _scene(rng)
    helper_name = bridge.helper_scene(create=False).name
    path = str(tmp_path / "scene.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path, copy=True)
    assert bridge.helper_scene(create=False).camera == scene.camera  # given back after saving
    with bpy.data.libraries.load(path, link=True) as (source, target):
        target.scenes = [helper_name]
    linked = next(s for s in bpy.data.scenes if s.library is not None)
    assert linked.camera is None and len(linked.objects) == 0


def test_files_are_saved_with_compositing_on(rng, tmp_path):
    """Compositing switched off by hand is saved on in a scene with splats (in the file only): a
    Blender without the add-on would otherwise skip the compositor (and the helper's "no camera"
    error) and write frames without splats. Without splats the user's choice stands."""
    scene = _scene(rng)
    scene.render.use_compositing = False
    path = str(tmp_path / "splats.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path, copy=True)
    with bpy.data.libraries.load(path, link=True) as (source, target):
        target.scenes = [scene.name]
    assert not scene.render.use_compositing   # on in the file only
    linked = next(s for s in bpy.data.scenes if s.library is not None and s.name == scene.name)
    assert linked.render.use_compositing
    bs.reset_scene()
    plain = bpy.context.scene
    plain.render.use_compositing = False
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "plain.blend"), copy=True)
    assert not plain.render.use_compositing


def test_files_are_saved_with_their_view_layers_off(rng, tmp_path):
    """In the file, a bridged scene's view layers are off (a Blender without the add-on goes
    straight to the helper scene's "no camera" instead of rendering the meshes first); in the
    session, and when the add-on opens the file, they are as the user left them."""
    scene = _scene(rng)
    kept_off = scene.view_layers.new("Kept Off")
    kept_off.use = False
    path = str(tmp_path / "layers.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path, copy=True)
    assert [layer.use for layer in scene.view_layers] == [True, False]  # given back
    assert bridge.LAYERS_FLAG not in scene
    with bpy.data.libraries.load(path, link=True) as (source, target):
        target.scenes = [scene.name]
    linked = next(s for s in bpy.data.scenes if s.library is not None and s.name == scene.name)
    assert not any(layer.use for layer in linked.view_layers)
    assert list(linked[bridge.LAYERS_FLAG]) == [scene.view_layers[0].name]
    bridge.switch_on_layers(linked)   # a linked scene stays as its file holds it
    assert not any(layer.use for layer in linked.view_layers) and bridge.LAYERS_FLAG in linked
    name = scene.name
    bpy.ops.wm.open_mainfile(filepath=path)   # load_post switches them back on
    scene = bpy.data.scenes[name]
    assert [layer.use for layer in scene.view_layers] == [True, False]
    assert bridge.LAYERS_FLAG not in scene


def test_an_older_files_helper_camera_goes_on_load(rng, tmp_path):
    _scene(rng)
    helper = bridge.helper_scene(create=False)
    old = bpy.data.objects.new(bridge.HELPER_CAMERA, bpy.data.cameras.new(bridge.HELPER_CAMERA))
    helper.collection.objects.link(old)
    helper.camera = old
    helper.name = ".Splat Composite"     # and the name earlier versions gave it
    path = str(tmp_path / "old.blend")   # saved with it, as earlier versions saved
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)   # load_post tidies it
    helper = bridge.helper_scene(create=False)
    assert bridge.HELPER_CAMERA not in bpy.data.objects and len(helper.objects) == 0
    assert helper.camera == bpy.context.scene.camera is not None
    # the name a Blender without the extension shows in its error names the extension
    assert helper.name == bridge.HELPER_SCENE and "Gaussian Splatting extension" in helper.name


def test_a_script_saved_file_carries_the_bridge(rng, tmp_path):
    """Blender up to 5.0 sets the bridge up when a render starts; a script that adds splats and
    saves at once must still save a file that a Blender without the add-on refuses to render
    (the bridge, the helper scene without a camera), not one it renders without splats."""
    bs.reset_scene()
    scene = bpy.context.scene
    splat_object.create_splat_object(random_gaussians(rng, 50, 1, radius=1.0), "Splats")
    bs.add_camera()
    path = str(tmp_path / "script.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path, copy=True)
    assert bridge.bridge_node(scene) is not None
    with bpy.data.libraries.load(path, link=True) as (source, target):
        target.scenes = list(source.scenes)
    linked = {s.name: s for s in bpy.data.scenes if s.library is not None}
    helper = next(s for s in linked.values() if s.get(bridge.HELPER_FLAG))
    assert helper.camera is None and len(helper.objects) == 0
    assert bridge.bridge_node(linked[scene.name]) is not None
