"""Editing operators for splat objects: crop, select by a measure, clean up floaters.

They act on the splat objects being edited (Edit Mode) or the selected splat objects (Object
Mode), on their original mesh data (modifiers stay on top), with every measure taken in world
space (the object's transform applied). Each is undoable and reports what it did.

- `bpy.ops.splat.crop(shape='BOX'|'SPHERE', volume="", center, size, radius, invert)`: removes the
  splats whose centre lies outside a world-space box (centre, full size, axis aligned) or sphere
  (centre, radius), or, with `volume` naming an object, outside that object's box (an Empty:
  its display cube, `empty_display_size` each side of its origin; anything else: its local
  bounding box) or the ellipsoid inscribed in that box, moved, rotated and scaled with the object.
  `invert=True` removes the inside instead. Given neither `volume` nor `center`, a selected
  non-splat object (the active one first) is the volume, else the shape is centred on the 3D
  cursor.
- `bpy.ops.splat.select_by(criterion='OPACITY'|'SIZE'|'DISTANCE', compare='BELOW'|'ABOVE',
  threshold, action='SET'|'EXTEND'|'SUBTRACT')`: selects vertices (splats) by opacity
  (sigmoid of the logit, 0..1), size (largest standard deviation, `exp(max log_scale)`, times the
  object's uniform scale `|det M|^(1/3)`) or distance of the centre from the 3D cursor (world
  units). Hidden vertices are never selected.
- `bpy.ops.splat.clean_up(...)`: removes floaters (transparent, tiny or isolated splats, see
  `addon.core.cleanup`); invoked from the UI it shows how many of each would go before it runs;
  `select_only=True` selects them instead. `find_floaters(obj, ...)` gives scripts the masks.
- `bpy.ops.splat.join()`: joins the selected splat objects into the active one. Blender's own
  Join (Ctrl+J) moves the other objects' vertex positions into the active object's space but
  not their rotations, scales or SH, which is only right when the objects share a transform;
  this one transforms every splat parameter first (`bake_transform`), then joins.
- `bpy.ops.splat.apply_transform()`: bakes each selected splat object's own transform
  (location, rotation, scale) into its splats, SH included, and resets it to identity (Blender's
  Apply Transform would move the centres only). Children keep their place.
"""

from __future__ import annotations

import bpy
import numpy as np
from bpy.props import BoolProperty, EnumProperty, FloatProperty, FloatVectorProperty, IntProperty, \
    StringProperty

from ..core.cleanup import FloaterMasks, floater_masks
from ..core.gaussians import sigmoid
from ..core.transform import transform_gaussians
from . import splat_object
from .registration import module_registration


def target_objects(context) -> list:
    """Splat objects in Edit Mode, or else the selected splat objects (and the active one)."""
    if context.mode == "EDIT_MESH":
        objects = list(getattr(context, "objects_in_mode", []) or [context.edit_object])
    else:
        objects = list(getattr(context, "selected_objects", []))
        active = context.active_object
        if active is not None and active not in objects:
            objects.append(active)
    return [o for o in objects if splat_object.is_splat_object(o)]


def _matrix(obj) -> np.ndarray:
    return np.array(obj.matrix_world, dtype=np.float64)


def _read_points(mesh, name: str, width: int, key: str) -> np.ndarray:
    n = len(mesh.vertices)
    out = np.empty(n * width, np.float32)
    attribute = mesh.attributes.get(name)
    if attribute is None:
        raise splat_object.SplatDataError(f"mesh {mesh.name!r} has no attribute {name!r}")
    if n:
        attribute.data.foreach_get(key, out)
    return out.reshape(n, width) if width > 1 else out


def world_positions(obj) -> np.ndarray:
    local = _read_points(obj.data, splat_object.POSITION, 3, "vector").astype(np.float64)
    m = _matrix(obj)
    return local @ m[:3, :3].T + m[:3, 3]


def uniform_scale(obj) -> float:
    return float(abs(np.linalg.det(_matrix(obj)[:3, :3])) ** (1.0 / 3.0))


def world_sizes(obj) -> np.ndarray:
    """Largest standard deviation of each splat, times the object's uniform scale."""
    log_scales = _read_points(obj.data, splat_object.LOG_SCALE, 3, "vector")
    return np.exp(log_scales.max(axis=1).astype(np.float64)) * uniform_scale(obj)


def opacities(obj) -> np.ndarray:
    return sigmoid(_read_points(obj.data, splat_object.OPACITY_LOGIT, 1, "value"))


def _hidden(mesh) -> np.ndarray:
    hide = splat_object.hidden_mask(mesh)
    return np.zeros(len(mesh.vertices), bool) if hide is None else hide


# --------------------------------------------------------------------------------------------
# Crop

def volume_inside(points: np.ndarray, shape: str, *, volume=None, center=(0.0, 0.0, 0.0),
                  size=(2.0, 2.0, 2.0), radius: float = 1.0) -> np.ndarray:
    """Which world-space points lie in the crop volume (see the module docstring)."""
    points = np.asarray(points, np.float64)
    if volume is not None:
        m = _matrix(volume)
        if abs(np.linalg.det(m[:3, :3])) < 1e-30:
            raise ValueError(f"crop volume {volume.name!r} has zero scale")
        local = (points - m[:3, 3]) @ np.linalg.inv(m[:3, :3]).T
        if volume.type == "EMPTY":
            half = np.full(3, volume.empty_display_size, np.float64)
            middle = np.zeros(3)
        else:
            corners = np.array([tuple(c) for c in volume.bound_box], np.float64)
            lo, hi = corners.min(axis=0), corners.max(axis=0)
            middle, half = (lo + hi) / 2, (hi - lo) / 2
    else:
        local = points
        middle = np.asarray(center, np.float64)
        half = (np.asarray(size, np.float64) / 2 if shape == "BOX"
                else np.full(3, float(radius)))
    offset = local - middle
    if shape == "BOX":
        return np.all(np.abs(offset) <= half, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        scaled = np.where(half > 0, offset / np.where(half > 0, half, 1.0),
                          np.where(offset == 0, 0.0, np.inf))
    return np.einsum("ij,ij->i", scaled, scaled) <= 1.0


class SPLAT_OT_crop(bpy.types.Operator):
    """Remove the splats outside (or inside) a box or sphere"""

    bl_idname = "splat.crop"
    bl_label = "Crop Splats"
    bl_options = {"REGISTER", "UNDO"}

    shape: EnumProperty(name="Shape", items=[
        ("BOX", "Box", "Keep the splats inside a box"),
        ("SPHERE", "Sphere", "Keep the splats inside a sphere (an ellipsoid for a scaled volume "
                             "object)")], default="BOX")
    volume: StringProperty(
        name="Volume Object",
        description="Crop to this object's box (an Empty's display cube, or the bounding box) or "
                    "the ellipsoid inside it; empty: use Center, Size and Radius",
        options={"SKIP_SAVE"})
    center: FloatVectorProperty(name="Center", subtype="XYZ", unit="LENGTH", size=3,
                                options={"SKIP_SAVE"})
    size: FloatVectorProperty(name="Size", subtype="XYZ", unit="LENGTH", size=3, min=0.0,
                              default=(2.0, 2.0, 2.0), description="Full size of the box")
    radius: FloatProperty(name="Radius", unit="LENGTH", min=0.0, default=1.0)
    invert: BoolProperty(name="Remove Inside", description="Remove the splats inside instead",
                         default=False)

    @classmethod
    def poll(cls, context):
        return bool(target_objects(context))

    def _defaults(self, context) -> None:
        """Without `volume` or `center`: a selected non-splat object (the active one first) is
        the volume; failing that the shape is centred on the 3D cursor."""
        if self.volume or self.properties.is_property_set("center"):
            return
        targets = target_objects(context)
        others = [o for o in getattr(context, "selected_objects", []) if o not in targets]
        active = context.active_object
        if active is not None and active in others:
            self.volume = active.name
        elif others:
            self.volume = others[0].name
        else:
            self.center = context.scene.cursor.location

    def execute(self, context):
        self._defaults(context)
        volume = None
        if self.volume:
            volume = context.scene.objects.get(self.volume) or bpy.data.objects.get(self.volume)
            if volume is None:
                self.report({"ERROR"}, f"No object named {self.volume!r}")
                return {"CANCELLED"}
        targets = target_objects(context)
        if not targets:
            self.report({"ERROR"}, "No splat object to crop")
            return {"CANCELLED"}
        removed = total = 0
        with splat_object.ObjectModeFor(context):
            for obj in targets:
                if obj is volume:
                    continue
                try:
                    inside = volume_inside(world_positions(obj), self.shape, volume=volume,
                                           center=self.center, size=self.size, radius=self.radius)
                except ValueError as error:
                    self.report({"ERROR"}, str(error))
                    return {"CANCELLED"}
                keep = ~inside if self.invert else inside
                total += len(keep)
                removed += splat_object.remove_points(obj, keep)
        self.report({"INFO"}, f"Removed {removed:,} of {total:,} splats")
        return {"FINISHED"}


# --------------------------------------------------------------------------------------------
# Select by

MEASURES = {
    "OPACITY": opacities,
    "SIZE": world_sizes,
    "DISTANCE": None,  # needs the cursor
}


def measure(obj, criterion: str, cursor=(0.0, 0.0, 0.0)) -> np.ndarray:
    if criterion == "DISTANCE":
        return np.linalg.norm(world_positions(obj) - np.asarray(cursor, np.float64), axis=1)
    return MEASURES[criterion](obj)


class SPLAT_OT_select_by(bpy.types.Operator):
    """Select splats by opacity, size, or distance from the 3D cursor"""

    bl_idname = "splat.select_by"
    bl_label = "Select Splats By"
    bl_options = {"REGISTER", "UNDO"}

    criterion: EnumProperty(name="By", items=[
        ("OPACITY", "Opacity", "Opacity, 0 to 1"),
        ("SIZE", "Size", "Largest standard deviation, in world units"),
        ("DISTANCE", "Distance from Cursor", "Distance of the centre from the 3D cursor, in "
                                             "world units")], default="OPACITY")
    compare: EnumProperty(name="Compare", items=[
        ("BELOW", "Below", "Select where the measure is below the threshold"),
        ("ABOVE", "Above", "Select where the measure is above the threshold")], default="BELOW")
    threshold: FloatProperty(name="Threshold", default=0.1, min=0.0)
    action: EnumProperty(name="Action", items=[
        ("SET", "Set", "Replace the selection"),
        ("EXTEND", "Extend", "Add to the selection"),
        ("SUBTRACT", "Subtract", "Remove from the selection")], default="SET")

    @classmethod
    def poll(cls, context):
        return bool(target_objects(context))

    def execute(self, context):
        targets = target_objects(context)
        if not targets:
            self.report({"ERROR"}, "No splat object")
            return {"CANCELLED"}
        cursor = tuple(context.scene.cursor.location)
        count = 0
        with splat_object.ObjectModeFor(context) as mode:
            for obj in targets:
                mesh = obj.data
                values = measure(obj, self.criterion, cursor)
                hit = values < self.threshold if self.compare == "BELOW" else values > self.threshold
                current = np.zeros(len(mesh.vertices), bool)
                if len(current):
                    mesh.vertices.foreach_get("select", current)
                if self.action == "SET":
                    selected = hit
                elif self.action == "EXTEND":
                    selected = current | hit
                else:
                    selected = current & ~hit
                selected &= ~_hidden(mesh)
                if len(selected):
                    mesh.vertices.foreach_set("select", selected)
                mesh.update()
                count += int(selected.sum())
            if mode.was_edit:
                context.tool_settings.mesh_select_mode = (True, False, False)
        self.report({"INFO"}, f"{count:,} splats selected")
        return {"FINISHED"}


# --------------------------------------------------------------------------------------------
# Clean up

def find_floaters(obj, *, min_opacity: float | None = 0.01, min_size_fraction: float | None = 0.05,
                  radius: float | None = None, min_neighbours: int | None = 3) -> FloaterMasks:
    """Floater masks of `obj`'s splats (original mesh data, world space); None turns a test off,
    `radius=None` picks it automatically (see `addon.core.cleanup`)."""
    mesh = obj.data
    log_scales = _read_points(mesh, splat_object.LOG_SCALE, 3, "vector")
    logits = _read_points(mesh, splat_object.OPACITY_LOGIT, 1, "value")
    return floater_masks(world_positions(obj), log_scales, logits, min_opacity=min_opacity,
                         min_size_fraction=min_size_fraction, radius=radius,
                         min_neighbours=min_neighbours)


class SPLAT_OT_clean_up(bpy.types.Operator):
    """Remove floaters: transparent, tiny or isolated splats (shows how many first)"""

    bl_idname = "splat.clean_up"
    bl_label = "Clean Up Splats"
    bl_options = {"REGISTER", "UNDO"}

    use_opacity: BoolProperty(name="Transparent", default=True,
                              description="Remove splats less opaque than Min Opacity")
    min_opacity: FloatProperty(name="Min Opacity", default=0.01, min=0.0, max=1.0)
    use_size: BoolProperty(
        name="Tiny", default=True,
        description="Remove splats smaller than a fraction of the median size")
    min_size_fraction: FloatProperty(
        name="Min Size (of median)", default=0.05, min=0.0, max=1.0, subtype="FACTOR")
    use_isolated: BoolProperty(
        name="Isolated", default=True,
        description="Remove splats with few neighbours around them")
    radius: FloatProperty(name="Radius", default=0.0, min=0.0, unit="LENGTH",
                          description="Neighbourhood size in world units; 0: 2% of the extent "
                                      "of the central 98% of the splats")
    min_neighbours: IntProperty(name="Min Neighbours", default=3, min=1, max=1000)
    select_only: BoolProperty(name="Select Only",
                              description="Select the floaters (Edit Mode) instead of removing "
                                          "them", default=False)

    _preview: dict = {}

    @classmethod
    def poll(cls, context):
        return bool(target_objects(context))

    def _params(self) -> dict:
        return dict(min_opacity=self.min_opacity if self.use_opacity else None,
                    min_size_fraction=self.min_size_fraction if self.use_size else None,
                    radius=self.radius or None,
                    min_neighbours=self.min_neighbours if self.use_isolated else None)

    def _masks(self, context) -> list[tuple[object, FloaterMasks]]:
        return [(obj, find_floaters(obj, **self._params())) for obj in target_objects(context)]

    def preview(self, context) -> dict[str, int]:
        """Counts of what would go, for the dialog; cached on the settings and the meshes."""
        targets = target_objects(context)
        key = (tuple(sorted(self._params().items(), key=lambda kv: kv[0])),
               tuple((o.name, len(o.data.vertices), tuple(map(tuple, o.matrix_world)))
                     for o in targets))
        cache = SPLAT_OT_clean_up._preview
        if cache.get("key") != key:
            totals = {"transparent": 0, "tiny": 0, "isolated": 0, "total": 0, "splats": 0}
            for obj, masks in self._masks(context):
                for name, value in masks.counts().items():
                    totals[name] += value
                totals["splats"] += len(masks.any)
            cache.clear()
            cache.update(key=key, counts=totals)
        return cache["counts"]

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        for enabled, value in (("use_opacity", "min_opacity"), ("use_size", "min_size_fraction"),
                               ("use_isolated", "radius")):
            row = layout.row(heading="")
            row.prop(self, enabled)
            sub = row.row()
            sub.active = getattr(self, enabled)
            sub.prop(self, value, text="")
        row = layout.row()
        row.active = self.use_isolated
        row.prop(self, "min_neighbours")
        layout.prop(self, "select_only")
        counts = self.preview(context)
        box = layout.box()
        box.label(text=f"{counts['total']:,} of {counts['splats']:,} splats will go",
                  icon="TRASH")
        box.label(text=f"transparent {counts['transparent']:,}, tiny {counts['tiny']:,}, "
                       f"isolated {counts['isolated']:,}")

    def invoke(self, context, event):
        if context.mode == "EDIT_MESH":  # the preview reads mesh data: write the edits back
            for obj in target_objects(context):
                obj.update_from_editmode()
        SPLAT_OT_clean_up._preview.clear()
        return context.window_manager.invoke_props_dialog(self, width=380)

    def execute(self, context):
        if not target_objects(context):
            self.report({"ERROR"}, "No splat object")
            return {"CANCELLED"}
        totals = {"transparent": 0, "tiny": 0, "isolated": 0, "total": 0}
        count = 0
        with splat_object.ObjectModeFor(context) as mode:
            for obj, masks in self._masks(context):
                for name, value in masks.counts().items():
                    totals[name] += value
                count += len(masks.any)
                if self.select_only:
                    mesh = obj.data
                    selected = masks.any & ~_hidden(mesh)
                    if len(selected):
                        mesh.vertices.foreach_set("select", selected)
                    mesh.update()
                else:
                    splat_object.remove_points(obj, ~masks.any)
            if self.select_only and mode.was_edit:
                context.tool_settings.mesh_select_mode = (True, False, False)
        verb = "Selected" if self.select_only else "Removed"
        self.report({"INFO"}, f"{verb} {totals['total']:,} of {count:,} splats "
                              f"(transparent {totals['transparent']:,}, tiny {totals['tiny']:,}, "
                              f"isolated {totals['isolated']:,})")
        return {"FINISHED"}


# --------------------------------------------------------------------------------------------
# Join, apply transform

def bake_transform(obj, matrix: np.ndarray) -> None:
    """Transform the splats in `obj`'s mesh by `matrix` (centres, rotations, scales, SH), in
    place; every other attribute, hidden and selected flags included, stays as it is."""
    mesh = obj.data
    gaussians = splat_object.gaussians_from_data(mesh, drop_hidden=False)
    splat_object.write_gaussians(mesh, transform_gaussians(gaussians, matrix))


class SPLAT_OT_join(bpy.types.Operator):
    """Join the selected splat objects into the active one, transforming every splat parameter
    (rotation, scale and SH too, which Blender's Join leaves as they were)"""

    bl_idname = "splat.join"
    bl_label = "Join Splats"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return context.mode == "OBJECT" and splat_object.is_splat_object(context.active_object)

    def execute(self, context):
        active = context.active_object
        if not splat_object.is_splat_object(active):
            self.report({"ERROR"}, "The active object is not a splat object")
            return {"CANCELLED"}
        others = [o for o in context.selected_objects
                  if o is not active and splat_object.is_splat_object(o)]
        skipped = [o.name for o in context.selected_objects
                   if o is not active and not splat_object.is_splat_object(o)]
        if not others:
            self.report({"ERROR"}, "Select splat objects to join into the active one")
            return {"CANCELLED"}
        for obj in others:
            if obj.data.users > 1 or obj.data is active.data:
                self.report({"ERROR"}, f"{obj.name!r} shares its mesh; make it single user first")
                return {"CANCELLED"}
        target = np.array(active.matrix_world, dtype=np.float64)
        inverse = np.linalg.inv(target)
        for obj in others:
            relative = inverse @ np.array(obj.matrix_world, dtype=np.float64)
            bake_transform(obj, relative)
            obj.matrix_world = active.matrix_world  # so Join moves nothing again
        context.view_layer.update()
        with context.temp_override(active_object=active, object=active,
                                   selected_objects=[active] + others,
                                   selected_editable_objects=[active] + others):
            bpy.ops.object.join()
        if skipped:
            self.report({"WARNING"}, f"Not splat objects, left out: {', '.join(skipped)}")
        self.report({"INFO"}, f"Joined {len(others)} object(s) into {active.name}")
        return {"FINISHED"}


class SPLAT_OT_apply_transform(bpy.types.Operator):
    """Bake the selected splat objects' own transforms into their splats (SH rotated too) and
    reset the transforms"""

    bl_idname = "splat.apply_transform"
    bl_label = "Apply Transform to Splats"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return context.mode == "OBJECT" and bool(target_objects(context))

    def execute(self, context):
        import mathutils

        targets = target_objects(context)
        for obj in targets:
            if obj.data.users > 1:
                self.report({"ERROR"}, f"{obj.name!r} shares its mesh; make it single user first")
                return {"CANCELLED"}
        for obj in targets:
            basis = obj.matrix_basis.copy()
            bake_transform(obj, np.array(basis, dtype=np.float64))
            obj.matrix_basis = mathutils.Matrix.Identity(4)
            for child in obj.children:
                child.matrix_parent_inverse = basis @ child.matrix_parent_inverse
        self.report({"INFO"}, f"Applied the transform of {len(targets)} splat object(s)")
        return {"FINISHED"}


class VIEW3D_MT_splat(bpy.types.Menu):
    bl_idname = "VIEW3D_MT_splat"
    bl_label = "Gaussian Splats"

    def draw(self, context):
        layout = self.layout
        layout.operator(SPLAT_OT_crop.bl_idname, text="Crop")
        layout.operator(SPLAT_OT_select_by.bl_idname, text="Select By")
        layout.operator(SPLAT_OT_clean_up.bl_idname, text="Clean Up")
        layout.separator()
        layout.operator(SPLAT_OT_join.bl_idname, text="Join")
        layout.operator(SPLAT_OT_apply_transform.bl_idname, text="Apply Transform")


def _menu(self, context):
    self.layout.menu(VIEW3D_MT_splat.bl_idname)


def _select_menu(self, context):
    self.layout.operator(SPLAT_OT_select_by.bl_idname, text="Splats By Opacity/Size/Distance")


CLASSES = (SPLAT_OT_crop, SPLAT_OT_select_by, SPLAT_OT_clean_up, SPLAT_OT_join,
           SPLAT_OT_apply_transform, VIEW3D_MT_splat)
_MENUS = (("VIEW3D_MT_object", _menu), ("VIEW3D_MT_edit_mesh", _menu),
          ("VIEW3D_MT_select_edit_mesh", _select_menu))


register, unregister = module_registration(CLASSES, menus=_MENUS)
