"""The splat object: a mesh with one vertex per Gaussian and its parameters as point attributes.

Attribute names (all on the POINT domain, object space; see docs/guide/blender.md, "The splat object"):

    position       FLOAT_VECTOR  the Gaussian's centre (the vertex position)
    rotation       QUATERNION    orientation w, x, y, z (need not be normalised; all zero = identity);
                                 geometry nodes read it as a Rotation
    log_scale      FLOAT_VECTOR  natural log of the standard deviation along each local axis
                                 (scale = exp(log_scale))
    opacity_logit  FLOAT         opacity = 1 / (1 + exp(-opacity_logit))
    sh_0 .. sh_15  FLOAT_VECTOR  spherical-harmonics coefficients, RGB each: sh_0 the DC term
                                 (band 0), sh_1..3 band 1, sh_4..8 band 2, sh_9..15 band 3, in the
                                 3DGS order; the data's SH degree is the highest complete band

The values are exactly the ones in `Gaussians` (float32, no conversion), so Gaussians -> object
-> Gaussians is bit-exact. Everything is moved with `foreach_get` / `foreach_set` on whole arrays:
no Python loop over vertices.

Hidden vertices (Edit Mode > Hide, stored in `.hide_vert`) are left out of renders and exports.
"""

from __future__ import annotations

import bpy
import numpy as np

from ..core.gaussians import Gaussians, sh_count

POSITION = "position"
ROTATION = "rotation"
LOG_SCALE = "log_scale"
OPACITY_LOGIT = "opacity_logit"
HIDE = ".hide_vert"
MAX_SH_COEFFICIENTS = 16


def sh_name(k: int) -> str:
    return f"sh_{k}"


SH_NAMES = tuple(sh_name(k) for k in range(MAX_SH_COEFFICIENTS))
# name -> (data type, foreach property, values per point)
REQUIRED = {
    ROTATION: ("QUATERNION", "value", 4),
    LOG_SCALE: ("FLOAT_VECTOR", "vector", 3),
    OPACITY_LOGIT: ("FLOAT", "value", 1),
    SH_NAMES[0]: ("FLOAT_VECTOR", "vector", 3),
}
SH_TYPE = ("FLOAT_VECTOR", "vector", 3)
ATTRIBUTE_NAMES = (POSITION, ROTATION, LOG_SCALE, OPACITY_LOGIT) + SH_NAMES


class SplatDataError(ValueError):
    """An object's geometry does not hold splats (attributes missing or of the wrong type)."""


def _matches(attribute, spec) -> bool:
    return attribute.domain == "POINT" and attribute.data_type == spec[0]


def missing_attributes(data) -> list[str]:
    """The required splat attributes `data` (a Mesh or PointCloud) lacks or holds with the wrong
    type or domain."""
    attributes = data.attributes
    missing = []
    for name, spec in REQUIRED.items():
        attribute = attributes.get(name)
        if attribute is None or not _matches(attribute, spec):
            missing.append(name)
    return missing


def data_sh_degree(data) -> int | None:
    """The SH degree `data` holds (its highest complete band), or None if it is not splat data."""
    if data is None or not hasattr(data, "attributes") or missing_attributes(data):
        return None
    attributes = data.attributes
    degree = 0
    for candidate in (1, 2, 3):
        names = SH_NAMES[sh_count(candidate - 1):sh_count(candidate)]
        if all((a := attributes.get(n)) is not None and _matches(a, SH_TYPE) for n in names):
            degree = candidate
        else:
            break
    return degree


def is_splat_object(obj) -> bool:
    """Made by this add-on (the `splat.is_splat` flag) and a mesh."""
    settings = getattr(obj, "splat", None)
    return obj is not None and obj.type == "MESH" and settings is not None and settings.is_splat


def _read(attribute, width: int, key: str, n: int, dtype=np.float32) -> np.ndarray:
    out = np.empty(n * width, dtype)
    if n:
        attribute.data.foreach_get(key, out)
    return out.reshape((n, width) if width > 1 else (n,))


def _write(attributes, name: str, spec: tuple, values: np.ndarray) -> None:
    data_type, key, _ = spec
    attribute = attributes.get(name)
    if attribute is not None and not _matches(attribute, spec):
        attributes.remove(attribute)
        attribute = None
    if attribute is None:
        attribute = attributes.new(name, data_type, "POINT")
    if len(values):
        attribute.data.foreach_set(key, np.ascontiguousarray(values, np.float32).reshape(-1))


def point_count(data) -> int:
    position = data.attributes.get(POSITION)
    return len(position.data) if position is not None else 0


def hidden_mask(data) -> np.ndarray | None:
    """The vertices of a mesh hidden in Edit Mode (`.hide_vert`), None where none is."""
    attribute = data.attributes.get(HIDE)
    if attribute is None or attribute.domain != "POINT" or attribute.data_type != "BOOLEAN":
        return None
    n = len(attribute.data)
    hide = np.empty(n, bool)
    if n:
        attribute.data.foreach_get("value", hide)
    return hide if hide.any() else None


def gaussians_from_data(data, *, drop_hidden: bool = True) -> Gaussians:
    """The Gaussians a Mesh or PointCloud holds, in its own (object) space.

    Raises SplatDataError if the splat attributes are missing. With `drop_hidden`, vertices hidden
    in Edit Mode are left out."""
    degree = data_sh_degree(data)
    if degree is None:
        raise SplatDataError(f"{data.name!r} holds no splats: missing or mistyped attributes "
                             f"{', '.join(missing_attributes(data))}")
    attributes = data.attributes
    n = point_count(data)
    means = _read(attributes[POSITION], 3, "vector", n)
    quats = _read(attributes[ROTATION], 4, "value", n)
    log_scales = _read(attributes[LOG_SCALE], 3, "vector", n)
    opacity = _read(attributes[OPACITY_LOGIT], 1, "value", n)
    k = sh_count(degree)
    sh = np.empty((n, k, 3), np.float32)
    buffer = np.empty(n * 3, np.float32)
    for index in range(k):
        if n:
            attributes[SH_NAMES[index]].data.foreach_get("vector", buffer)
        sh[:, index, :] = buffer.reshape(n, 3)
    gaussians = Gaussians(means, log_scales, quats, opacity, sh)
    if drop_hidden:
        hide = hidden_mask(data)
        if hide is not None and len(hide) == n:
            gaussians = gaussians.subset(~hide)
    return gaussians


def write_gaussians(mesh: bpy.types.Mesh, gaussians: Gaussians) -> None:
    """Write `gaussians` into the splat attributes of `mesh`, which must have one vertex per
    Gaussian. SH attributes beyond the Gaussians' degree are removed."""
    n = len(gaussians)
    if len(mesh.vertices) != n:
        raise ValueError(f"mesh {mesh.name!r} has {len(mesh.vertices)} vertices, expected {n}")
    attributes = mesh.attributes
    if n:
        attributes[POSITION].data.foreach_set("vector", gaussians.means.reshape(-1))
    _write(attributes, ROTATION, REQUIRED[ROTATION], gaussians.quats)
    _write(attributes, LOG_SCALE, REQUIRED[LOG_SCALE], gaussians.log_scales)
    _write(attributes, OPACITY_LOGIT, REQUIRED[OPACITY_LOGIT], gaussians.opacity_logits)
    k = gaussians.sh.shape[1]
    for index in range(MAX_SH_COEFFICIENTS):
        if index < k:
            _write(attributes, SH_NAMES[index], SH_TYPE, gaussians.sh[:, index, :])
        elif (extra := attributes.get(SH_NAMES[index])) is not None:
            attributes.remove(extra)
    mesh.update()


def mesh_from_gaussians(gaussians: Gaussians, name: str) -> bpy.types.Mesh:
    """A new vertex-only mesh holding `gaussians` (removed again if anything fails)."""
    bad = gaussians.non_finite()
    if bad is not None:
        raise ValueError(f"Gaussians.{bad} holds NaN or Inf")
    mesh = bpy.data.meshes.new(name)
    try:
        mesh.vertices.add(len(gaussians))
        write_gaussians(mesh, gaussians)
    except BaseException:
        bpy.data.meshes.remove(mesh)
        raise
    return mesh


def replace_gaussians(obj, gaussians: Gaussians) -> None:
    """Rewrite a splat object's mesh with `gaussians` (any count; the mesh is kept)."""
    bad = gaussians.non_finite()
    if bad is not None:
        raise ValueError(f"Gaussians.{bad} holds NaN or Inf")
    mesh = obj.data
    if len(mesh.vertices) != len(gaussians):
        mesh.clear_geometry()
        mesh.vertices.add(len(gaussians))
    write_gaussians(mesh, gaussians)
    settings = obj.splat
    if settings.sh_degree > gaussians.degree or not settings.is_splat:
        settings.sh_degree = gaussians.degree
    settings.is_splat = True
    if bpy.context.scene is not None:
        sync_display(obj, bpy.context.scene)


def new_object(name: str, data, datablocks) -> bpy.types.Object:
    """`bpy.data.objects.new(name, data)`; if that fails, `data` is removed from `datablocks`
    (e.g. `bpy.data.meshes`) so nothing is left behind."""
    try:
        return bpy.data.objects.new(name, data)
    except BaseException:
        datablocks.remove(data)
        raise


def create_splat_object(gaussians: Gaussians, name: str = "Splats", *, collection=None,
                        antialiased: bool = False, sh_degree: int | None = None,
                        color_space: str = "SRGB", source_path: str = "") -> bpy.types.Object:
    """A new splat object holding `gaussians` in its local space, linked to `collection` (the
    scene's master collection when None). Nothing is left behind if it fails."""
    mesh = mesh_from_gaussians(gaussians, name)
    obj = new_object(name, mesh, bpy.data.meshes)
    try:
        settings = obj.splat
        settings.is_splat = True
        settings.antialiased = bool(antialiased)
        settings.sh_degree = gaussians.degree if sh_degree is None else int(sh_degree)
        settings.color_space = color_space
        settings.source_path = source_path
        if collection is None:
            collection = bpy.context.scene.collection
        collection.objects.link(obj)
        if bpy.context.scene is not None:
            sync_display(obj, bpy.context.scene)
    except BaseException:
        bpy.data.objects.remove(obj)
        bpy.data.meshes.remove(mesh)
        raise
    return obj


# --------------------------------------------------------------------------------------------
# How Blender itself draws the object
#
# Blender draws a mesh without faces as dots, one per vertex, on top of everything drawn from
# Python (overlays are merged after the add-on's POST_VIEW image): 125k dots over the splats. A
# splat object the add-on draws is displayed as its bounding box instead (`display_type =
# 'BOUNDS'`: a few lines to see and click it, no dots); Edit Mode still shows and selects every
# point. When the add-on stops drawing it (its or the scene's "Show in Viewport" off), the dots
# come back. The display is set where the object is made (so the undo step of the operator that
# made it holds it); `viewport` re-syncs it after undo, redo, load, append and duplicate.

BOUNDS_FLAG = "splat_bounds_display"   # ID property: this add-on set the bounds display


def drawn_by_addon(obj, scene) -> bool:
    settings = getattr(scene, "splat_render", None)
    return (getattr(obj, "splat", None) is not None and obj.splat.is_splat
            and obj.splat.show_in_viewport and (settings is None or settings.viewport))


def sync_display(obj, scene) -> bool:
    """Bounds display while the add-on draws the splats, Blender's own otherwise. True if it
    changed anything.

    A display the user picked is left alone: Wire, or Textured/Solid on an object the add-on
    had already given Bounds (it still carries BOUNDS_FLAG). Linked (library) objects are
    read-only and left as their file has them."""
    if not getattr(getattr(obj, "splat", None), "is_splat", False) or obj.library is not None:
        return False
    if drawn_by_addon(obj, scene):
        if obj.display_type in ("TEXTURED", "SOLID") and not obj.get(BOUNDS_FLAG):
            obj.display_type = "BOUNDS"
            obj[BOUNDS_FLAG] = True
            return True
    elif obj.display_type == "BOUNDS" and obj.get(BOUNDS_FLAG):
        obj.display_type = "TEXTURED"
        del obj[BOUNDS_FLAG]
        return True
    return False


def needs_sync(obj, scene) -> bool:
    """Whether `sync_display` would change `obj` (cheap: no data written)."""
    if not getattr(getattr(obj, "splat", None), "is_splat", False) or obj.library is not None:
        return False
    if drawn_by_addon(obj, scene):
        return obj.display_type in ("TEXTURED", "SOLID") and not obj.get(BOUNDS_FLAG)
    return obj.display_type == "BOUNDS" and bool(obj.get(BOUNDS_FLAG))


# --------------------------------------------------------------------------------------------
# Removing points (crop, clean up)

# data type -> (foreach property, values per element, numpy dtype) for a generic exact copy
_GENERIC = {
    "FLOAT": ("value", 1, np.float32),
    "INT": ("value", 1, np.int32),
    "BOOLEAN": ("value", 1, bool),
    "FLOAT_VECTOR": ("vector", 3, np.float32),
    "FLOAT2": ("vector", 2, np.float32),
    "QUATERNION": ("value", 4, np.float32),
    "FLOAT_COLOR": ("color", 4, np.float32),
    "INT32_2D": ("value", 2, np.int32),
    "FLOAT4X4": ("value", 16, np.float32),
}


def _rebuildable(obj, mesh) -> bool:
    """A plain point mesh whose every attribute the fast path can copy exactly."""
    if len(mesh.edges) or len(mesh.polygons) or mesh.shape_keys is not None:
        return False
    if obj is not None and len(obj.vertex_groups):
        return False
    for attribute in mesh.attributes:
        if attribute.domain == "POINT" and attribute.data_type not in _GENERIC:
            return False
        if attribute.domain not in ("POINT", "EDGE", "FACE", "CORNER"):
            return False
    return True


def remove_points(obj, keep: np.ndarray) -> int:
    """Delete the vertices of `obj`'s mesh where `keep` is False, keeping every attribute of
    the others. Object Mode only. Returns how many were removed.

    Point meshes (the usual splat object) are rebuilt with whole-array copies; anything else
    (edges, faces, shape keys, vertex groups, unusual attribute types) goes through BMesh."""
    mesh = obj.data
    keep = np.asarray(keep, bool)
    n = len(mesh.vertices)
    if keep.shape != (n,):
        raise ValueError(f"keep mask has shape {keep.shape}, mesh has {n} vertices")
    removed = int(n - keep.sum())
    if removed == 0:
        return 0
    if _rebuildable(obj, mesh):
        _rebuild_points(mesh, keep)
    else:
        _bmesh_remove(mesh, keep)
    mesh.update()
    return removed


def _rebuild_points(mesh, keep: np.ndarray) -> None:
    n = len(mesh.vertices)
    saved = []
    for attribute in mesh.attributes:
        if attribute.domain != "POINT":
            if not attribute.name.startswith("."):  # Blender's own ones survive clear_geometry
                saved.append((attribute.name, attribute.data_type, attribute.domain, None))
            continue
        key, width, dtype = _GENERIC[attribute.data_type]
        values = np.empty(n * width, dtype)
        attribute.data.foreach_get(key, values)
        saved.append((attribute.name, attribute.data_type, attribute.domain,
                      values.reshape(n, width)[keep].reshape(-1)))
    active = mesh.attributes.active.name if mesh.attributes.active is not None else None
    active_color = mesh.color_attributes.active_color_name
    render_color = mesh.color_attributes.default_color_name
    mesh.clear_geometry()
    mesh.vertices.add(int(keep.sum()))
    for name, data_type, domain, values in saved:
        attribute = mesh.attributes.get(name)
        if attribute is None:
            attribute = mesh.attributes.new(name, data_type, domain)
        if values is not None and len(values):
            attribute.data.foreach_set(_GENERIC[data_type][0], values)
    if active is not None and (attribute := mesh.attributes.get(active)) is not None:
        mesh.attributes.active = attribute
    if active_color and active_color in mesh.color_attributes:
        mesh.color_attributes.active_color_name = active_color
    if render_color and render_color in mesh.color_attributes:
        mesh.color_attributes.default_color_name = render_color


def _bmesh_remove(mesh, keep: np.ndarray) -> None:
    import bmesh

    bm = bmesh.new()
    try:
        bm.from_mesh(mesh)
        bm.verts.ensure_lookup_table()
        doomed = [bm.verts[i] for i in np.flatnonzero(~keep).tolist()]
        bmesh.ops.delete(bm, geom=doomed, context="VERTS")
        bm.to_mesh(mesh)
    finally:
        bm.free()


# --------------------------------------------------------------------------------------------
# Mode handling for operators that change mesh data


class ObjectModeFor:
    """`with ObjectModeFor(context):` leaves Edit Mode (writing the edit mesh back) for the body
    and returns to it afterwards, so mesh data can be read and written directly."""

    def __init__(self, context) -> None:
        self.context = context
        self.was_edit = context.mode in ("EDIT_MESH", "EDIT_POINTCLOUD")

    def __enter__(self):
        if self.was_edit:
            bpy.ops.object.mode_set(mode="OBJECT")
        return self

    def __exit__(self, *exc) -> None:
        if self.was_edit:
            bpy.ops.object.mode_set(mode="EDIT")

