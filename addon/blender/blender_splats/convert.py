"""Add-on splat object <-> Blender 5.3 splat point cloud, from scripts and from Object > Convert.

    obj = to_blender_splats(splat_obj)     # a point cloud of type GAUSSIAN_SPLAT
    obj = from_blender_splats(cloud_obj)   # an add-on splat object (mesh)

Lossless up to float32 rounding of exp/log and sigmoid/logit (`core.blender_splats.attributes`):
positions, scales, rotations, opacities and SH bands 0-3 of every point (hidden ones included),
in object space, so the object's transform carries the placement. What carries over with it:
name, parent and local transform, collections, materials, visibility (viewport, render,
selectable and the ray visibility the user set), and the add-on's own render options
(`Object.splat`). Blender's splats of SH degree 4 come back with bands 0-3 and a warning.
By default the source object is replaced, as Blender's own Convert does (`keep_original`).
"""

from __future__ import annotations

import bpy
from bpy.props import BoolProperty

from .. import splat_object
from ..registration import module_registration
from . import data, ownership

_VISIBILITY = ("hide_viewport", "hide_render", "hide_select") + ownership.RAY_VISIBILITY
TRAINED_OBJECT_KEY = "splat_object"  # train.operator.OBJECT_KEY
_SETTINGS = ("antialiased", "sh_degree", "color_space", "source_path", "show_in_viewport")


def _carry_over(source, target) -> None:
    target.parent = source.parent
    target.parent_type = source.parent_type
    target.matrix_parent_inverse = source.matrix_parent_inverse.copy()
    target.matrix_basis = source.matrix_basis.copy()
    target.rotation_mode = source.rotation_mode
    saved = source.get(ownership.SAVED)  # the user's ray visibility, not the add-on's
    for name in _VISIBILITY:
        if hasattr(source, name):
            value = getattr(source, name)
            if saved is not None and name in saved:
                value = bool(saved[name])
            setattr(target, name, value)
    for name in _SETTINGS:
        setattr(target.splat, name, getattr(source.splat, name))
    for material in source.data.materials:
        target.data.materials.append(material)
    for collection in source.users_collection:
        if target.name not in collection.objects:
            collection.objects.link(target)
    for collection in bpy.data.collections:  # training's "the collection's splat object"
        if collection.get(TRAINED_OBJECT_KEY) == source:
            collection[TRAINED_OBJECT_KEY] = target
    for child in list(source.children):
        matrix = child.matrix_world.copy()
        child.parent = target
        child.matrix_world = matrix


def _replace(source, target, keep_original: bool) -> None:
    name = source.name
    for view_layer in (bpy.context.view_layer,):
        if view_layer.objects.active == source:
            view_layer.objects.active = target
        if source.name in view_layer.objects and source.select_get(view_layer=view_layer):
            target.select_set(True, view_layer=view_layer)
            source.select_set(False, view_layer=view_layer)
    if keep_original:
        return
    old_data = source.data
    bpy.data.objects.remove(source)
    if old_data.users == 0:
        (bpy.data.meshes if isinstance(old_data, bpy.types.Mesh) else bpy.data.pointclouds).remove(old_data)
    target.name = name
    target.data.name = name


def to_blender_splats(obj, *, keep_original: bool = False):
    """The add-on splat object `obj` as a Blender splat point cloud object (Blender 5.3+)."""
    data.require_support()
    if not splat_object.is_splat_object(obj):
        raise splat_object.SplatDataError(f"{obj.name!r} is not an add-on splat object")
    gaussians = splat_object.gaussians_from_data(obj.data, drop_hidden=False)
    target = data.create_object(gaussians, obj.name, collection=None)
    try:
        bpy.context.scene.collection.objects.unlink(target)
        _carry_over(obj, target)
        if not target.users_collection:
            bpy.context.scene.collection.objects.link(target)
        ownership.sync_object(target)
    except BaseException:
        cloud = target.data
        bpy.data.objects.remove(target)
        bpy.data.pointclouds.remove(cloud)
        raise
    _replace(obj, target, keep_original)
    return target


def from_blender_splats(obj, *, keep_original: bool = False) -> tuple[object, list[str]]:
    """The Blender splat point cloud object `obj` as an add-on splat object, and warnings
    (bands beyond degree 3 left out, splats with NaN or Inf left out)."""
    if not data.is_blender_splat_object(obj):
        raise splat_object.SplatDataError(f"{obj.name!r} is not a Blender splat point cloud")
    conversion = data.read_conversion(obj.data, drop_hidden=False)
    target = splat_object.create_splat_object(conversion.gaussians, obj.name)
    try:
        bpy.context.scene.collection.objects.unlink(target)
        _carry_over(obj, target)
        if not target.users_collection:
            bpy.context.scene.collection.objects.link(target)
        target.splat.is_splat = True
        target.splat.sh_degree = min(obj.splat.sh_degree, conversion.gaussians.degree)
    except BaseException:
        mesh = target.data
        bpy.data.objects.remove(target)
        bpy.data.meshes.remove(mesh)
        raise
    _replace(obj, target, keep_original)
    return target, conversion.warnings


class _Convert:
    bl_options = {"REGISTER", "UNDO"}
    keep_original: BoolProperty(name="Keep Original",
                                description="Keep the source object beside the new one",
                                default=False)

    @staticmethod
    def sources(context) -> list:
        raise NotImplementedError

    @classmethod
    def poll(cls, context):
        if not data.supported():
            cls.poll_message_set("Needs Blender 5.3 or later (Gaussian splat point clouds)")
            return False
        return bool(cls.sources(context))

    def execute(self, context):
        if context.mode != "OBJECT":
            bpy.ops.object.mode_set(mode="OBJECT")
        made, notes = [], []
        for obj in self.sources(context):
            try:
                result = self.convert(obj)
            except (ValueError, RuntimeError) as error:
                self.report({"ERROR"}, f"Cannot convert {obj.name}: {error}")
                return {"CANCELLED"}
            new, warnings = result if isinstance(result, tuple) else (result, [])
            made.append(new)
            notes += warnings
        for note in notes:
            self.report({"WARNING"}, note)
        self.report({"INFO"}, f"Converted {len(made)} object(s)")
        return {"FINISHED"}


class SPLAT_OT_convert_to_blender_splats(_Convert, bpy.types.Operator):
    """Convert the selected add-on splat objects to Blender's own Gaussian splat point clouds
    (Blender 5.3+), losslessly"""

    bl_idname = "splat.convert_to_blender_splats"
    bl_label = "Splats to Blender Splat Point Cloud"

    @staticmethod
    def sources(context) -> list:
        return [o for o in context.selected_objects if splat_object.is_splat_object(o)]

    def convert(self, obj):
        return to_blender_splats(obj, keep_original=self.keep_original)


class SPLAT_OT_convert_from_blender_splats(_Convert, bpy.types.Operator):
    """Convert the selected Blender splat point clouds to the add-on's splat objects (meshes with
    the splat attributes), losslessly for SH bands 0-3"""

    bl_idname = "splat.convert_from_blender_splats"
    bl_label = "Blender Splat Point Cloud to Splats"

    @staticmethod
    def sources(context) -> list:
        return [o for o in context.selected_objects if data.is_blender_splat_object(o)]

    def convert(self, obj):
        return from_blender_splats(obj, keep_original=self.keep_original)


def _menu(self, context):
    layout = self.layout
    layout.separator()
    layout.operator(SPLAT_OT_convert_to_blender_splats.bl_idname, icon="OUTLINER_OB_POINTCLOUD")
    layout.operator(SPLAT_OT_convert_from_blender_splats.bl_idname, icon="MESH_DATA")


CLASSES = (SPLAT_OT_convert_to_blender_splats, SPLAT_OT_convert_from_blender_splats)

_register, _unregister = module_registration(CLASSES, menus=[("VIEW3D_MT_object_convert", _menu)])


def register() -> None:
    _register()
    ownership.register()


def unregister() -> None:
    ownership.unregister()
    _unregister()
