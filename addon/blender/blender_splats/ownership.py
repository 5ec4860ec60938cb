"""One renderer per splat object: who draws a Blender splat point cloud, Blender or the add-on.

By default the add-on composes Blender's splat point clouds exactly (F12, `-a`, viewport), so
Blender must not also path-trace or draw them. For each such object the add-on:

- adds a render-only geometry-nodes modifier whose output is empty (`RENDER_MODIFIER`, shown
  in the modifier stack, off in the viewport) when the object has no modifier of its own: in
  final renders Cycles, EEVEE and Workbench then have nothing to draw or trace and spend no
  time on it (measured in bpy 5.3.0, 500k points: Cycles 0.02 s CPU per F12 against 0.45 s with
  ray visibility alone; Workbench draws nothing instead of the billboards), and `gather` reads
  the object's own data (`reads_original`) with the render's matrix for it;
- turns its ray visibility off (camera, diffuse, glossy, transmission, volume scatter, shadow:
  Cycles and EEVEE then neither show nor trace it; this is what keeps an object with modifiers
  of its own, which the add-on must read evaluated, out of Cycles' and EEVEE's images, and
  Material Preview's);
- shows it as its bounding box in the viewport while the add-on draws it (no EEVEE/Workbench billboards under the
add-on's drawing; with the object's or the scene's "Show in Viewport" off, Blender draws it). The user's own
values are kept in an ID property on the object and put back when the object is handed back to
Blender (`Object.splat.render_by_blender`), when it stops being a splat point cloud, or when
the add-on is disabled. The object stays render-visible, so the render depsgraph (and `gather`)
still sees it.

`sync_scene(scene)` runs on file load, when objects are added (depsgraph update), at render
init, after a save and when the per-object setting changes.

Saved files stay Blender's: before each save every object is handed back (`give_back`) and
after it taken again, so a file saved with the add-on and opened without it shows and renders
Blender's splats as Blender made them (before this, such a file kept the empty render modifier,
rays off and bounds display, with the user's values in an ID property only the add-on reads).
"""

from __future__ import annotations

import bpy
from bpy.app.handlers import persistent

from ..registration import module_registration
from . import data

RENDER_MODIFIER = "Splats: rendered by the add-on"  # a render-only, empty-output GN modifier
_EMPTY_GROUP = ".Splats Rendered by the Add-on"
RAY_VISIBILITY = ("visible_camera", "visible_diffuse", "visible_glossy", "visible_transmission",
                  "visible_volume_scatter", "visible_shadow")
SAVED = "splat_blender_visibility"   # ID property: the user's values while the add-on owns it
DISPLAY_SAVED = "splat_blender_display"


def rendered_by_addon(obj) -> bool:
    """A Blender splat object that the add-on renders (not handed back to Blender)."""
    return data.is_blender_splat_object(obj) and not getattr(
        getattr(obj, "splat", None), "render_by_blender", False)


def _empty_group():
    group = bpy.data.node_groups.get(_EMPTY_GROUP)
    if group is None or group.bl_idname != "GeometryNodeTree":
        group = bpy.data.node_groups.new(_EMPTY_GROUP, "GeometryNodeTree")
        group.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
        group.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
        group.nodes.new("NodeGroupInput")
        group.nodes.new("NodeGroupOutput")  # nothing linked: the output is empty
    return group


def _ours(obj):
    modifier = obj.modifiers.get(RENDER_MODIFIER)
    return modifier if modifier is not None and modifier.type == "NODES" else None


def reads_original(obj) -> bool:
    """`obj` (original) renders through the add-on's empty-output modifier, its only one: its
    splats are its own data, whatever a render depsgraph evaluates it to."""
    modifier = _ours(obj)
    return modifier is not None and len(obj.modifiers) == 1 and modifier.node_group is not None \
        and modifier.node_group.name == _EMPTY_GROUP


def _sync_modifier(obj, wanted: bool) -> None:
    modifier = _ours(obj)
    others = len(obj.modifiers) - (modifier is not None)
    if wanted and others == 0:
        if modifier is None:
            modifier = obj.modifiers.new(RENDER_MODIFIER, "NODES")
        if modifier.node_group is None or modifier.node_group.name != _EMPTY_GROUP:
            modifier.node_group = _empty_group()
        modifier.show_viewport = modifier.show_in_editmode = False
        modifier.show_render = True
    elif modifier is not None:
        obj.modifiers.remove(modifier)


def _take_rays(obj) -> None:
    if SAVED not in obj:
        obj[SAVED] = {name: bool(getattr(obj, name)) for name in RAY_VISIBILITY
                      if hasattr(obj, name)}
    for name in RAY_VISIBILITY:
        if hasattr(obj, name) and getattr(obj, name):
            setattr(obj, name, False)


def _give_rays_back(obj) -> None:
    saved = obj.get(SAVED)
    if saved is not None:
        for name, value in dict(saved).items():
            if hasattr(obj, name) and getattr(obj, name) != bool(value):
                setattr(obj, name, bool(value))
        del obj[SAVED]


def _show_bounds(obj) -> None:
    if DISPLAY_SAVED not in obj and obj.display_type in ("TEXTURED", "SOLID"):
        obj[DISPLAY_SAVED] = obj.display_type
        obj.display_type = "BOUNDS"


def _restore_display(obj) -> None:
    display = obj.get(DISPLAY_SAVED)
    if display is not None:
        if obj.display_type == "BOUNDS":
            obj.display_type = str(display)
        del obj[DISPLAY_SAVED]


def give_back(obj) -> None:
    """Put the user's ray visibility and display type back, and take the add-on's render
    modifier off (Blender renders it again)."""
    _give_rays_back(obj)
    _restore_display(obj)
    _sync_modifier(obj, False)


def drawn_by_addon(obj, scene=None) -> bool:
    """The add-on draws it in the viewport (its and the scene's viewport switches on)."""
    settings = getattr(scene, "splat_render", None) if scene is not None else None
    return rendered_by_addon(obj) and obj.splat.show_in_viewport and (
        settings is None or settings.viewport)


def sync_object(obj, scene=None) -> None:
    """Rays off and the render modifier on while the add-on renders it; bounds display while
    the add-on draws it."""
    if rendered_by_addon(obj):
        _take_rays(obj)
        _sync_modifier(obj, True)
    else:
        if SAVED in obj:
            _give_rays_back(obj)
        if _ours(obj) is not None:
            _sync_modifier(obj, False)
    if drawn_by_addon(obj, scene):
        _show_bounds(obj)
    elif DISPLAY_SAVED in obj:
        _restore_display(obj)


def sync_scene(scene) -> None:
    if not data.supported():
        return
    for obj in scene.objects:
        if obj.type == "POINTCLOUD" and (obj.library is None and obj.override_library is None):
            sync_object(obj, scene)


def on_setting_changed(settings, context) -> None:
    """Update callback of `Object.splat.render_by_blender`."""
    obj = settings.id_data
    if isinstance(obj, bpy.types.Object):
        sync_object(obj, context.scene)


_counts: dict[str, int] = {}


@persistent
def _on_depsgraph_update(scene, depsgraph) -> None:
    if getattr(depsgraph, "mode", "VIEWPORT") != "VIEWPORT" or not data.supported():
        return
    if not depsgraph.id_type_updated("OBJECT") and not depsgraph.id_type_updated("POINTCLOUD"):
        return
    counts = len(scene.objects)
    if _counts.get(scene.name) == counts and not depsgraph.id_type_updated("POINTCLOUD"):
        return
    _counts[scene.name] = counts
    if bpy.app.background:
        sync_scene(scene)
    else:  # never write ID properties inside the update itself in the UI
        name = scene.name
        bpy.app.timers.register(lambda: _sync_later(name), first_interval=0.0)


def _sync_later(scene_name: str) -> None:
    scene = bpy.data.scenes.get(scene_name)
    if scene is not None:
        sync_scene(scene)


@persistent
def _on_load_post(*_args) -> None:
    _counts.clear()
    for scene in bpy.data.scenes:
        sync_scene(scene)


@persistent
def _on_render_init(scene, _depsgraph=None) -> None:
    sync_scene(scene)


def _owned(obj) -> bool:
    return SAVED in obj or DISPLAY_SAVED in obj or (obj.type == "POINTCLOUD" and
                                                     _ours(obj) is not None)


@persistent
def _on_save_pre(*_args) -> None:
    for obj in bpy.data.objects:
        if obj.library is None and _owned(obj):
            give_back(obj)


@persistent
def _on_save_post(*_args) -> None:
    for scene in bpy.data.scenes:
        sync_scene(scene)


_HANDLERS = (("depsgraph_update_post", _on_depsgraph_update), ("load_post", _on_load_post),
             ("render_init", _on_render_init), ("save_pre", _on_save_pre),
             ("save_post", _on_save_post))


register, _unregister = module_registration(handlers=_HANDLERS)


def unregister() -> None:
    _unregister()
    _counts.clear()
    try:
        for obj in bpy.data.objects:
            if _owned(obj):
                give_back(obj)
    except AttributeError:  # restricted context (unregister during file load): leave them
        pass
