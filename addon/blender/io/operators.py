"""Import and export of splat files: functions for scripts, operators, menus, drag and drop.

Scripts:
    obj = import_splats("scene.ply")                  # a new splat object, selected and active
    export_splats(obj, "out.spz")                     # the evaluated object, in world space
or the operators `bpy.ops.splat.import_splats(filepath=...)` and
`bpy.ops.splat.export_splats(filepath=...)` (the active splat object). The format follows from the
file name, through the format table `core/formats/registry.py` (`FORMATS`, the one list): .ply
(standard 3DGS, and SuperSplat's .compressed.ply), .splat, .spz, SOG (.sog, a folder's
meta.json; a streamed lod-meta.json is read only), glTF (.glb, .gltf).

Import reads the whole file before touching the scene, so a bad file raises `SplatFileError`
(the operator reports it as an error) and leaves nothing behind.

Export writes what the object renders as: the *evaluated* geometry (modifiers and geometry
nodes applied, hidden vertices left out, instances it makes included), transformed by the world
matrix (positions, rotations, scales, and SH bands 1-3 rotated; a non-uniform scale is exact for
each Gaussian's shape and rotates the SH by the polar rotation, see `addon.core.transform`).
`world_space=False` writes the evaluated geometry in object space instead. .splat holds SH
degree 0 only (higher bands are dropped, with a warning); .spz records the antialiased option.

Axes (`forward_axis`, `up_axis`, as Blender's OBJ/glTF/PLY importers): which file axis becomes
Blender's forward (+Y) and up (+Z); "AUTO" takes the format's default from the format table
(`formats.registry`, forward Z and up -Y for every format today: the 3DGS/COLMAP frame is y
down, so captures from upright photos stand upright). Import keeps the conversion as the
object's transform (a -90 degree X rotation by default) and the data exactly as in the file;
export applies the inverse after the world matrix in one transform (SH rotated with it), so an
import then export with the same options writes the same numbers, bit for bit.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import bpy
from bpy.props import BoolProperty, CollectionProperty, EnumProperty, IntProperty, StringProperty
from bpy_extras.io_utils import ExportHelper, ImportHelper, poll_file_object_drop

import numpy as np

from ...core import axes
from ...core.formats import registry
from ...core.formats_common import limits
from ...core.formats_common.errors import SplatFileError
from ...core.formats.sequence import SplatSequence, save_sequence
from ...core.gaussians import Gaussians
from ...core.transform import transform_gaussians
from .. import splat_object
from ..sources import gather
from ..sources.edit_mesh import edit_mode_gaussians
from ..blender_splats import any_splats
from ..blender_splats import data as blender_data
from ..blender_splats import ownership
from . import sequence
from ..camera_adapter import to_matrix
from ..job_runner import draw_settings, preparing
from ..registration import module_registration

IMPORT_GLOB = registry.filter_glob()
_DIGITS_AT_END = re.compile(r"[_.\-]*\d+$")  # a frame number ending a name
EXPORT_GLOB = registry.filter_glob(registry.export_formats())


def read_splat_file(filepath: str | os.PathLike) -> tuple[Gaussians, bool]:
    """(Gaussians, antialiased) from a splat file; formats that do not record the antialiased
    mode give False."""
    return registry.read(Path(filepath))


def file_axes(filepath: str | os.PathLike, forward_axis: str | None = "AUTO",
              up_axis: str | None = "AUTO") -> np.ndarray:
    """The 4x4 taking the file's frame to Blender's for these options ("AUTO" or None: the
    format's default, see `formats.registry.SplatFormat.axes`). ValueError for a bad pair."""
    default_forward, default_up = registry.format_for(filepath).axes
    forward = default_forward if forward_axis in (None, "AUTO") else forward_axis
    up = default_up if up_axis in (None, "AUTO") else up_axis
    return axes.axis_matrix4(forward, up)


def import_splats(filepath: str | os.PathLike, *, name: str | None = None, collection=None,
                  context=None, forward_axis: str | None = "AUTO",
                  up_axis: str | None = "AUTO",
                  blender_splats: bool | None = None) -> bpy.types.Object:
    """Load a splat file into a new splat object (in `collection`, by default the active one),
    deselect everything else and make it active; the axis conversion becomes the object's
    transform (see the module docstring). `blender_splats=True` makes Blender 5.3's own splat
    point cloud instead of the add-on's object (None: `default_blender_splats()`); before 5.3
    it raises BlenderSplatsUnsupported. Raises SplatFileError for a bad file (ValueError for
    bad axes), with the scene unchanged."""
    context = context or bpy.context
    path = Path(filepath)
    if blender_splats is None:
        blender_splats = default_blender_splats()
    elif blender_splats:
        blender_data.require_support()
    matrix = file_axes(path, forward_axis, up_axis)
    gaussians, antialiased = read_splat_file(path)
    if collection is None:
        collection = getattr(context, "collection", None) or context.scene.collection
    obj = make_object(gaussians, name or path.stem, collection, antialiased, str(path),
                      blender_splats)
    obj.matrix_world = to_matrix(matrix)
    _select_only(obj, context.view_layer)
    return obj


# What File > Import makes in Blender 5.3+ when not told (see docs/benchmarks/blender_splats.md).
DEFAULT_BLENDER_SPLATS = False


def default_blender_splats() -> bool:
    """Whether imports make Blender's own splat point clouds when not told: only where this
    Blender has them, and then `DEFAULT_BLENDER_SPLATS`."""
    return DEFAULT_BLENDER_SPLATS and blender_data.supported()


def make_object(gaussians: Gaussians, name: str, collection, antialiased: bool, source: str,
                blender_splats: bool):
    """A new splat object of either kind holding `gaussians` in its local space."""
    if not blender_splats:
        return splat_object.create_splat_object(
            gaussians, name, collection=collection, antialiased=antialiased, source_path=source)
    obj = blender_data.create_object(gaussians, name, collection=collection)
    obj.splat.antialiased = bool(antialiased)
    obj.splat.sh_degree = gaussians.degree
    obj.splat.source_path = source
    ownership.sync_object(obj)
    return obj


def _select_only(obj, view_layer) -> None:
    view_layer.update()  # a newly linked object shows in the layer's objects after an update
    for other in view_layer.objects:
        if other.select_get(view_layer=view_layer):
            other.select_set(False, view_layer=view_layer)
    if obj.name in view_layer.objects:
        obj.select_set(True, view_layer=view_layer)
        view_layer.objects.active = obj


def _stored_path(path: Path, relative: bool) -> str:
    """`path` as a splat object stores it: relative to the saved .blend (`//frames/...`) when
    `relative`, so that it resolves wherever the .blend and its folder are mounted (a render
    farm's shared storage); absolute for an unsaved file or another drive."""
    if relative and bpy.data.filepath:
        try:
            return bpy.path.relpath(str(path))
        except ValueError:  # another drive (Windows): no relative path exists
            pass
    return str(path)


def import_sequence(target: str | os.PathLike, *, name: str | None = None, collection=None,
                    context=None, frame_offset: int = 0, forward_axis: str | None = "AUTO",
                    up_axis: str | None = "AUTO", relative: bool = False) -> bpy.types.Object:
    """Load a splat sequence (a numbered file and its siblings, a `####` pattern or a folder;
    see `core.formats.sequence`) as ONE splat object showing, at scene frame F, the file numbered
    F + `frame_offset` (see `sequence`). Only the current frame's file is read now. Raises
    SplatFileError (no frames, a bad file) with the scene unchanged."""
    context = context or bpy.context
    target = Path(target)
    splat_sequence = SplatSequence(target, cache_frames=sequence.CACHE_FRAMES)
    first_file = splat_sequence.files[splat_sequence.first]
    matrix = file_axes(first_file, forward_axis, up_axis)
    number = splat_sequence.number_for(context.scene.frame_current + frame_offset)
    gaussians = splat_sequence.gaussians(number)
    antialiased = registry.read(splat_sequence.files[number])[1] \
        if registry.format_for(first_file).stores_antialiased else False
    if collection is None:
        collection = getattr(context, "collection", None) or context.scene.collection
    stem = _DIGITS_AT_END.sub("", first_file.stem) or first_file.stem
    obj = splat_object.create_splat_object(
        gaussians, name or stem, collection=collection, antialiased=antialiased,
        source_path=str(target))
    obj.splat.sequence_source = _stored_path(target, relative)
    obj.splat.sequence_frame_offset = int(frame_offset)
    sequence.adopt(obj, splat_sequence)
    sequence.mark_shown(obj, number)
    sequence.record_numbers(obj, splat_sequence.numbers)
    obj.matrix_world = to_matrix(matrix)
    _select_only(obj, context.view_layer)
    return obj


def evaluated_gaussians(obj, depsgraph=None, *, world_space: bool = True,
                        space: np.ndarray | None = None) -> Gaussians:
    """What `obj` renders as (evaluated, hidden vertices dropped, instances it makes included),
    in world space or, with `world_space=False`, in its own space; then taken by the 4x4
    `space` (export's axis conversion; see `gather.gather`). Every SH band the data holds is
    kept, whatever the object's `sh_degree` render option says."""
    depsgraph = depsgraph or bpy.context.evaluated_depsgraph_get()
    if not world_space:
        evaluated = obj.evaluated_get(depsgraph)
        if evaluated.type == "MESH" and evaluated.data.is_editmode:
            local = edit_mode_gaussians(evaluated)
        else:
            local = any_splats.data_gaussians(evaluated.data)
        return local if space is None else transform_gaussians(local, axes.snap(space))
    result = gather.gather(depsgraph, objects=[obj], use_cache=False, all_sh_bands=True,
                           space=space, include_blender_rendered=True)
    if not result.batches:
        raise splat_object.SplatDataError(
            f"{obj.name!r} shows no splats (is it hidden, or do its modifiers remove the splat "
            f"attributes?)")
    return result.gaussians


def writable_format(path: Path) -> registry.SplatFormat:
    """The format a file named `path` is written in; SplatFileError for an ending no format
    writes or a missing folder."""
    fmt = registry.format_for(path)  # SplatFileError for an unknown ending
    if not fmt.can_write:
        raise SplatFileError(path, f"{fmt.name} files cannot be written")
    if not path.parent.is_dir():
        raise SplatFileError(path, f"folder {str(path.parent)!r} does not exist")
    return fmt


def export_splats(obj, filepath: str | os.PathLike, *, depsgraph=None,
                  world_space: bool = True, forward_axis: str | None = "AUTO",
                  up_axis: str | None = "AUTO") -> list[str]:
    """Write `obj` (see `evaluated_gaussians`) to `filepath`, Blender's frame taken to the
    file's by the axis options (the inverse of import's); the format follows from the name.
    Returns warnings (e.g. SH bands a format cannot hold)."""
    path = Path(filepath)
    fmt = writable_format(path)
    space = np.linalg.inv(file_axes(path, forward_axis, up_axis))
    gaussians = evaluated_gaussians(obj, depsgraph, world_space=world_space, space=space)
    antialiased = bool(getattr(getattr(obj, "splat", None), "antialiased", False))
    if not fmt.stores_antialiased:
        antialiased = False  # the format cannot say it; nothing to warn about on export
    return registry.write(gaussians, path, antialiased=antialiased)


def export_sequence(obj, pattern: str | os.PathLike, frames=None, *, scene=None,
                    world_space: bool = True, forward_axis: str | None = "AUTO",
                    up_axis: str | None = "AUTO") -> list[Path]:
    """Write `obj` at each scene frame of `frames` (default the scene's frame range) to
    `pattern` (`#` or `%04d` where the frame number goes, e.g. `out/walk_####.ply`), one file
    per frame as `export_splats` writes it, each atomically; only one frame is in memory at a
    time. The scene's frame is restored afterwards. Returns the files written."""
    scene = scene or bpy.context.scene
    pattern = Path(pattern)
    fmt = writable_format(pattern)
    frames = list(range(scene.frame_start, scene.frame_end + 1) if frames is None else frames)
    space = np.linalg.inv(file_axes(pattern, forward_axis, up_axis))
    antialiased = bool(obj.splat.antialiased) and fmt.stores_antialiased
    current = scene.frame_current, scene.frame_subframe

    def frames_in_world():
        for frame in frames:
            scene.frame_set(frame)
            yield frame, evaluated_gaussians(obj, bpy.context.evaluated_depsgraph_get(),
                                             world_space=world_space, space=space)

    try:
        return save_sequence(frames_in_world(), pattern, antialiased=antialiased)
    finally:
        scene.frame_set(current[0], subframe=current[1])


AXIS_ITEMS = [("AUTO", "Auto", "The file format's convention (3DGS .ply, .splat, .spz, SOG, "
                               "glTF: forward Z, up -Y)")] + [
    (name, name, "") for name in axes.AXES]


def _axis_prop(which: str, blender_axis: str) -> EnumProperty:
    return EnumProperty(name=which, items=AXIS_ITEMS, default="AUTO",
                        description=f"File axis that is Blender's {which.lower()} ({blender_axis})")


def _sequence_prop(name: str, description: str) -> BoolProperty:
    return BoolProperty(name=name, description=description, default=False)


class SPLAT_OT_import_splats(bpy.types.Operator, ImportHelper):
    """Import Gaussian splats (.ply, .spz, .splat, .sog, .glb, ...) as a splat object"""

    bl_idname = "splat.import_splats"
    bl_label = "Import Gaussian Splats"
    bl_options = {"REGISTER", "UNDO"}

    # SKIP_SAVE: a drop sets it; a stale remembered path must not turn File > Import into a popup
    filepath: StringProperty(subtype="FILE_PATH", options={"SKIP_SAVE", "HIDDEN"})
    filter_glob: StringProperty(default=IMPORT_GLOB, options={"HIDDEN"})
    files: CollectionProperty(type=bpy.types.OperatorFileListElement,
                              options={"HIDDEN", "SKIP_SAVE"})
    directory: StringProperty(subtype="DIR_PATH", options={"HIDDEN", "SKIP_SAVE"})
    forward_axis: _axis_prop("Forward", "+Y")
    up_axis: _axis_prop("Up", "+Z")
    sequence: _sequence_prop(
        "Import as Sequence", "The chosen file and its numbered siblings (walk_0001.ply, "
                              "walk_0002.ply, ...) as one splat object whose splats change with "
                              "the frame")
    representation: EnumProperty(
        name="Make", default="DEFAULT", options={"SKIP_SAVE"},
        items=[("DEFAULT", "Default", "Blender 5.3 and later: see the add-on's default; before "
                                      "5.3: the add-on's splat object"),
               ("ADDON", "Splat Object (add-on)", "The add-on's splat object: a mesh, one vertex "
                                                  "per splat, edited with Blender's mesh tools"),
               ("BLENDER", "Blender Splat Point Cloud",
                "Blender 5.3's own Gaussian splat point cloud (what File > Import > PLY makes); "
                "the add-on still renders, edits and exports it. Needs Blender 5.3")])
    max_expansion: IntProperty(
        name="Max Expansion", default=limits.MAX_EXPANSION, min=1, soft_max=100_000,
        description="Bytes of splats a file may declare per byte it holds: a file beyond is "
                    "refused as a decompression bomb (real files ask under 32). Raise it only "
                    "for a file you trust, e.g. a glTF that shows one splat model many times")
    relative_path: BoolProperty(
        name="Relative Path", default=True,
        description="Store a sequence's path relative to the saved .blend file (//frames/...), "
                    "so that it is found wherever the .blend and its frames are mounted, e.g. on "
                    "render farm workers")

    def paths(self) -> list[Path]:
        names = [f.name for f in self.files if f.name]
        if names and self.directory:
            return [Path(self.directory) / name for name in names]
        return [Path(self.filepath)] if self.filepath else []

    def invoke(self, context, event):
        return self.invoke_popup(context)

    def draw(self, context):
        layout = self.layout
        draw_settings(layout, self, ("forward_axis", "up_axis", "sequence", "max_expansion"))
        row = layout.row()
        row.enabled = blender_data.supported() and not self.sequence
        row.prop(self, "representation")

    def blender_splats(self) -> bool:
        if self.representation == "BLENDER":
            return True
        return self.representation == "DEFAULT" and default_blender_splats()

    def execute(self, context):
        paths = self.paths()
        if self.representation == "BLENDER" and not blender_data.supported():
            self.report({"ERROR"}, f"Blender {bpy.app.version_string} has no Gaussian splat "
                                   f"point clouds (Blender 5.3 and later)")
            return {"CANCELLED"}
        if not paths:
            self.report({"ERROR"}, "No file given")
            return {"CANCELLED"}
        if context.mode != "OBJECT" and context.active_object is not None:
            bpy.ops.object.mode_set(mode="OBJECT")
        if self.sequence:
            if self.representation == "BLENDER":
                self.report({"WARNING"}, "Sequences are imported as the add-on's splat object "
                                         "(Object > Convert makes a Blender splat point cloud)")
            return self.import_sequence(context, paths[0])
        loaded = []
        with preparing(context, "Importing splats", ", ".join(p.name for p in paths)) as progress:
            for k, path in enumerate(paths):
                progress(k / len(paths), "")
                try:
                    matrix = file_axes(path, self.forward_axis, self.up_axis)
                    with limits.expansion_bound(self.max_expansion):
                        gaussians, antialiased = read_splat_file(path)
                except (SplatFileError, OSError, ValueError) as error:
                    self.report({"ERROR"}, f"Cannot import: {error}")
                    return {"CANCELLED"}
                loaded.append((path, gaussians, antialiased, matrix))
        objects = []
        try:
            for path, gaussians, antialiased, matrix in loaded:
                obj = make_object(gaussians, path.stem,
                                  context.collection or context.scene.collection, antialiased,
                                  str(path), self.blender_splats())
                objects.append(obj)
                obj.matrix_world = to_matrix(matrix)
        except Exception as error:  # nothing half made: remove what this call created
            for obj in objects:
                geometry = obj.data
                bpy.data.objects.remove(obj)
                (bpy.data.meshes if isinstance(geometry, bpy.types.Mesh)
                 else bpy.data.pointclouds).remove(geometry)
            self.report({"ERROR"}, f"Cannot import: {error}")
            return {"CANCELLED"}
        view_layer = context.view_layer
        for other in context.selected_objects:
            other.select_set(False)
        for obj in objects:
            obj.select_set(True)
        view_layer.objects.active = objects[-1]
        total = sum(len(entry[1]) for entry in loaded)
        self.report({"INFO"}, f"Imported {total:,} splats from {len(loaded)} file(s)")
        return {"FINISHED"}

    def import_sequence(self, context, path: Path):
        try:
            obj = import_sequence(path, context=context, relative=self.relative_path,
                                  forward_axis=self.forward_axis,
                                  up_axis=self.up_axis)
        except (SplatFileError, OSError, ValueError) as error:
            self.report({"ERROR"}, f"Cannot import: {error}")
            return {"CANCELLED"}
        frames = sequence.sequence_of(obj)
        self.report({"INFO"}, f"Imported a sequence of {len(frames)} frames "
                              f"({frames.first}-{frames.last}) as {obj.name!r}")
        return {"FINISHED"}


class SPLAT_OT_export_splats(bpy.types.Operator, ExportHelper):
    """Export the active splat object (evaluated, in world space) in any format that writes splats"""

    bl_idname = "splat.export_splats"
    bl_label = "Export Gaussian Splats"
    bl_options = {"REGISTER"}  # writes a file, changes nothing to undo

    filename_ext = ".ply"
    filter_glob: StringProperty(default=EXPORT_GLOB, options={"HIDDEN"})
    world_space: BoolProperty(
        name="World Space",
        description="Apply the object's world transform (rotating the SH with it); off: write "
                    "the evaluated geometry in object space",
        default=True)
    forward_axis: _axis_prop("Forward", "+Y")
    up_axis: _axis_prop("Up", "+Z")
    sequence: _sequence_prop(
        "Export as Sequence", "One file per frame (the object as it is at that frame: "
                              "animated, deformed, a sequence); the name's # (or %04d) takes "
                              "the frame number (added before the extension when missing)")
    use_scene_range: BoolProperty(
        name="Scene Frame Range",
        description="Export the scene's frame range; off: the frames from Start to End",
        default=True)
    frame_start: IntProperty(name="Start", description="First frame exported (Scene Frame "
                                                       "Range off)", default=1)
    frame_end: IntProperty(name="End", description="Last frame exported (Scene Frame Range "
                                                   "off)", default=250)

    @classmethod
    def poll(cls, context):
        return any_splats.is_splat_source(context.active_object)

    def invoke(self, context, event):
        if not self.properties.is_property_set("frame_start"):
            self.frame_start = context.scene.frame_start
        if not self.properties.is_property_set("frame_end"):
            self.frame_end = context.scene.frame_end
        return super().invoke(context, event)

    def frames(self, scene) -> range:
        """The frames a sequence export writes."""
        if self.use_scene_range:
            return range(scene.frame_start, scene.frame_end + 1)
        return range(self.frame_start, self.frame_end + 1)

    def check(self, context):
        # Keep any ending a format writes (".sog", "meta.json", ...); add .ply otherwise.
        path = self.filepath
        name = os.path.basename(path).lower()
        if name and not any(f.matches(name) for f in registry.export_formats()):
            self.filepath = bpy.path.ensure_ext(path, self.filename_ext)
            return True
        return False

    def execute(self, context):
        obj = context.active_object
        if not any_splats.is_splat_source(obj):
            self.report({"ERROR"}, "The active object is not a splat object")
            return {"CANCELLED"}
        if self.sequence:
            target = sequence.sequence_pattern(self.filepath)
            frames = self.frames(context.scene)
            if not frames:
                self.report({"ERROR"}, f"Cannot export: no frames from {self.frame_start} to "
                                       f"{self.frame_end}")
                return {"CANCELLED"}

            def write() -> tuple[list[str], str]:
                written = export_sequence(obj, target, frames, scene=context.scene,
                                          world_space=self.world_space,
                                          forward_axis=self.forward_axis, up_axis=self.up_axis)
                return [], f"Exported {len(written)} frames of {obj.name} to {target}"
        else:
            target = self.filepath

            def write() -> tuple[list[str], str]:
                warnings = export_splats(obj, target, depsgraph=context.evaluated_depsgraph_get(),
                                         world_space=self.world_space,
                                         forward_axis=self.forward_axis, up_axis=self.up_axis)
                return warnings, f"Exported {obj.name} to {target}"
        try:
            # One stage: the cursor's counter in the UI, a terminal line headless.
            with preparing(context, "Exporting", f"{obj.name} to {Path(target).name}") \
                    as progress:
                progress(0.0, "")
                warnings, message = write()
                progress(1.0, "")
        except (SplatFileError, splat_object.SplatDataError, OSError, ValueError) as error:
            self.report({"ERROR"}, f"Cannot export: {error}")
            return {"CANCELLED"}
        for warning in warnings:
            self.report({"WARNING"}, warning)
        self.report({"INFO"}, message)
        return {"FINISHED"}


class SPLAT_FH_splats(bpy.types.FileHandler):
    bl_idname = "SPLAT_FH_splats"
    # Blender 5.3 offers its own PLY/SPZ importers for the same drop: say what this one does.
    bl_label = "Gaussian Splats - add-on importer (all splat formats)"
    bl_import_operator = "splat.import_splats"
    bl_file_extensions = registry.file_extensions()  # .json: format_for then decides

    @classmethod
    def poll_drop(cls, context):
        return poll_file_object_drop(context)


def _menu_import(self, context):
    self.layout.operator(SPLAT_OT_import_splats.bl_idname, text="Gaussian Splats (.ply, .spz, .sog, .glb, ...)")


def _menu_export(self, context):
    self.layout.operator(SPLAT_OT_export_splats.bl_idname, text="Gaussian Splats (.ply, .spz, .sog, .glb, ...)")


CLASSES = (SPLAT_OT_import_splats, SPLAT_OT_export_splats, SPLAT_FH_splats)


register, unregister = module_registration(
    CLASSES, menus=[("TOPBAR_MT_file_import", _menu_import), ("TOPBAR_MT_file_export", _menu_export)])
