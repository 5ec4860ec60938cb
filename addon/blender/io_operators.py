"""Import and export of splat files: functions for scripts, operators, menus, drag and drop.

Scripts:
    obj = import_splats("scene.ply")                  # a new splat object, selected and active
    export_splats(obj, "out.spz")                     # the evaluated object, in world space
or the operators `bpy.ops.splat.import_splats(filepath=...)` and
`bpy.ops.splat.export_splats(filepath=...)` (the active splat object). The format follows from the
extension: .ply (standard 3DGS; SuperSplat's compressed .ply is read too), .splat, .spz.

Import reads the whole file before touching the scene, so a bad file raises `SplatFileError`
(the operator reports it as an error) and leaves nothing behind.

Export writes what the object renders as: the *evaluated* geometry (modifiers and geometry
nodes applied, hidden vertices left out, instances it makes included), transformed by the world
matrix (positions, rotations, scales, and SH bands 1-3 rotated; a non-uniform scale is exact for
each Gaussian's shape and rotates the SH by the polar rotation, see `addon.core.transform`).
`world_space=False` writes the evaluated geometry in object space instead. .splat holds SH
degree 0 only (higher bands are dropped, with a warning); .spz records the antialiased option.
"""

from __future__ import annotations

import os
from pathlib import Path

import bpy
from bpy.props import BoolProperty, CollectionProperty, StringProperty
from bpy_extras.io_utils import ExportHelper, ImportHelper, poll_file_object_drop

from ..core import splat_io
from ..core.formats.errors import SplatFileError
from ..core.gaussians import Gaussians
from . import gather, splat_object
from .registration import register_classes, unregister_classes

FILTER_GLOB = "*.ply;*.splat;*.spz"


def read_splat_file(filepath: str | os.PathLike) -> tuple[Gaussians, bool]:
    """(Gaussians, antialiased) from a splat file; only .spz records the antialiased mode."""
    path = Path(filepath)
    if path.suffix.lower() == ".spz":
        from ..core.formats import spz

        packed = spz.read_packed(path)
        return spz.unpack(packed, path), bool(packed.antialiased)
    return splat_io.load(path), False


def import_splats(filepath: str | os.PathLike, *, name: str | None = None, collection=None,
                  context=None) -> bpy.types.Object:
    """Load a splat file into a new splat object (in `collection`, by default the active one),
    deselect everything else and make it active. Raises SplatFileError for a bad file, with the
    scene unchanged."""
    context = context or bpy.context
    path = Path(filepath)
    gaussians, antialiased = read_splat_file(path)
    if collection is None:
        collection = getattr(context, "collection", None) or context.scene.collection
    obj = splat_object.create_splat_object(
        gaussians, name or path.stem, collection=collection, antialiased=antialiased,
        source_path=str(path))
    view_layer = context.view_layer
    for other in view_layer.objects:
        if other.select_get(view_layer=view_layer):
            other.select_set(False, view_layer=view_layer)
    if obj.name in view_layer.objects:
        obj.select_set(True, view_layer=view_layer)
        view_layer.objects.active = obj
    return obj


def evaluated_gaussians(obj, depsgraph=None, *, world_space: bool = True) -> Gaussians:
    """What `obj` renders as (evaluated, hidden vertices dropped, instances it makes included),
    in world space or, with `world_space=False`, in its own space. Every SH band the data holds
    is kept, whatever the object's `sh_degree` render option says."""
    depsgraph = depsgraph or bpy.context.evaluated_depsgraph_get()
    if not world_space:
        evaluated = obj.evaluated_get(depsgraph)
        if evaluated.type == "MESH" and evaluated.data.is_editmode:
            return gather.edit_mode_gaussians(evaluated)
        return splat_object.gaussians_from_data(evaluated.data)
    result = gather.gather(depsgraph, objects=[obj], use_cache=False, all_sh_bands=True)
    if not result.batches:
        raise splat_object.SplatDataError(
            f"{obj.name!r} shows no splats (is it hidden, or do its modifiers remove the splat "
            f"attributes?)")
    return result.gaussians


def export_splats(obj, filepath: str | os.PathLike, *, depsgraph=None,
                  world_space: bool = True) -> list[str]:
    """Write `obj` (see `evaluated_gaussians`) to `filepath`; the format follows from the
    extension. Returns warnings (e.g. SH bands a format cannot hold)."""
    path = Path(filepath)
    suffix = path.suffix.lower()
    if suffix not in splat_io.SUFFIXES:
        raise SplatFileError(path, f"unknown splat format {suffix or '(no extension)'!r}; "
                                   f"expected one of {', '.join(splat_io.SUFFIXES)}")
    if not path.parent.is_dir():
        raise SplatFileError(path, f"folder {str(path.parent)!r} does not exist")
    gaussians = evaluated_gaussians(obj, depsgraph, world_space=world_space)
    warnings = []
    if suffix == ".splat" and gaussians.degree > 0:
        warnings.append(f".splat holds SH degree 0 only: bands 1-{gaussians.degree} were dropped")
        gaussians = gaussians.with_degree(0)
    if suffix == ".spz":
        from ..core.formats import spz

        antialiased = bool(getattr(getattr(obj, "splat", None), "antialiased", False))
        spz.save(gaussians, path, antialiased=antialiased)
    else:
        splat_io.save(gaussians, path)
    return warnings


class SPLAT_OT_import_splats(bpy.types.Operator, ImportHelper):
    """Import Gaussian splats (.ply, .splat, .spz) as a splat object"""

    bl_idname = "splat.import_splats"
    bl_label = "Import Gaussian Splats"
    bl_options = {"REGISTER", "UNDO"}

    # SKIP_SAVE: a drop sets it; a stale remembered path must not turn File > Import into a popup
    filepath: StringProperty(subtype="FILE_PATH", options={"SKIP_SAVE", "HIDDEN"})
    filter_glob: StringProperty(default=FILTER_GLOB, options={"HIDDEN"})
    files: CollectionProperty(type=bpy.types.OperatorFileListElement,
                              options={"HIDDEN", "SKIP_SAVE"})
    directory: StringProperty(subtype="DIR_PATH", options={"HIDDEN", "SKIP_SAVE"})

    def paths(self) -> list[Path]:
        names = [f.name for f in self.files if f.name]
        if names and self.directory:
            return [Path(self.directory) / name for name in names]
        return [Path(self.filepath)] if self.filepath else []

    def invoke(self, context, event):
        return self.invoke_popup(context)

    def execute(self, context):
        paths = self.paths()
        if not paths:
            self.report({"ERROR"}, "No file given")
            return {"CANCELLED"}
        if context.mode != "OBJECT" and context.active_object is not None:
            bpy.ops.object.mode_set(mode="OBJECT")
        loaded = []
        for path in paths:
            try:
                gaussians, antialiased = read_splat_file(path)
            except (SplatFileError, OSError) as error:
                self.report({"ERROR"}, f"Cannot import: {error}")
                return {"CANCELLED"}
            loaded.append((path, gaussians, antialiased))
        objects = []
        try:
            for path, gaussians, antialiased in loaded:
                objects.append(splat_object.create_splat_object(
                    gaussians, path.stem, collection=context.collection or context.scene.collection,
                    antialiased=antialiased, source_path=str(path)))
        except Exception as error:  # nothing half made: remove what this call created
            for obj in objects:
                mesh = obj.data
                bpy.data.objects.remove(obj)
                bpy.data.meshes.remove(mesh)
            self.report({"ERROR"}, f"Cannot import: {error}")
            return {"CANCELLED"}
        view_layer = context.view_layer
        for other in context.selected_objects:
            other.select_set(False)
        for obj in objects:
            obj.select_set(True)
        view_layer.objects.active = objects[-1]
        total = sum(len(g) for _, g, _ in loaded)
        self.report({"INFO"}, f"Imported {total:,} splats from {len(loaded)} file(s)")
        return {"FINISHED"}


class SPLAT_OT_export_splats(bpy.types.Operator, ExportHelper):
    """Export the active splat object (evaluated, in world space) as .ply, .splat or .spz"""

    bl_idname = "splat.export_splats"
    bl_label = "Export Gaussian Splats"
    bl_options = {"REGISTER"}  # writes a file, changes nothing to undo

    filename_ext = ".ply"
    filter_glob: StringProperty(default=FILTER_GLOB, options={"HIDDEN"})
    world_space: BoolProperty(
        name="World Space",
        description="Apply the object's world transform (rotating the SH with it); off: write "
                    "the evaluated geometry in object space",
        default=True)

    @classmethod
    def poll(cls, context):
        return splat_object.is_splat_object(context.active_object)

    def check(self, context):
        # Keep any of the three extensions the user typed; add .ply otherwise.
        path = self.filepath
        if os.path.basename(path) and Path(path).suffix.lower() not in splat_io.SUFFIXES:
            self.filepath = bpy.path.ensure_ext(path, self.filename_ext)
            return True
        return False

    def execute(self, context):
        obj = context.active_object
        if not splat_object.is_splat_object(obj):
            self.report({"ERROR"}, "The active object is not a splat object")
            return {"CANCELLED"}
        try:
            warnings = export_splats(obj, self.filepath,
                                     depsgraph=context.evaluated_depsgraph_get(),
                                     world_space=self.world_space)
        except (SplatFileError, splat_object.SplatDataError, OSError, ValueError) as error:
            self.report({"ERROR"}, f"Cannot export: {error}")
            return {"CANCELLED"}
        for warning in warnings:
            self.report({"WARNING"}, warning)
        self.report({"INFO"}, f"Exported {obj.name} to {self.filepath}")
        return {"FINISHED"}


class SPLAT_FH_splats(bpy.types.FileHandler):
    bl_idname = "SPLAT_FH_splats"
    bl_label = "Gaussian Splats"
    bl_import_operator = "splat.import_splats"
    bl_file_extensions = ".ply;.splat;.spz"

    @classmethod
    def poll_drop(cls, context):
        return poll_file_object_drop(context)


def _menu_import(self, context):
    self.layout.operator(SPLAT_OT_import_splats.bl_idname, text="Gaussian Splats (.ply, .splat, .spz)")


def _menu_export(self, context):
    self.layout.operator(SPLAT_OT_export_splats.bl_idname, text="Gaussian Splats (.ply, .splat, .spz)")


CLASSES = (SPLAT_OT_import_splats, SPLAT_OT_export_splats, SPLAT_FH_splats)


def register() -> None:
    register_classes(CLASSES)
    bpy.types.TOPBAR_MT_file_import.remove(_menu_import)
    bpy.types.TOPBAR_MT_file_export.remove(_menu_export)
    bpy.types.TOPBAR_MT_file_import.append(_menu_import)
    bpy.types.TOPBAR_MT_file_export.append(_menu_export)


def unregister() -> None:
    bpy.types.TOPBAR_MT_file_import.remove(_menu_import)
    bpy.types.TOPBAR_MT_file_export.remove(_menu_export)
    unregister_classes(CLASSES)
