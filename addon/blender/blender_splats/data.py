"""Read and write Blender's own splat point clouds (5.3+) with whole-array `foreach_get/set`.

The attribute convention (names, exp/log scales, sigmoid/logit opacity, SH layout, degree 4) is
`addon.core.blender_splats.attributes`; this module only moves arrays between it and bpy:

    supported()                  this Blender has point clouds of type 'GAUSSIAN_SPLAT'
    is_blender_splat_data(data)  a PointCloud (original or evaluated) of that type
    is_blender_splat_object(obj) an object whose data is one (its evaluated data may differ)
    degree_of(data)              -> (SH degree, notes on bands left out)
    read_conversion(data)        -> Conversion (object-space Gaussians, drops and warnings)
    new_pointcloud(gaussians, name) -> a PointCloud of type GAUSSIAN_SPLAT holding them
    create_object(gaussians, name, collection=...) -> a new object holding that point cloud
"""

from __future__ import annotations

import bpy
import numpy as np

from ...core.blender_splats import attributes
from ...core.gaussians import Gaussians
from .. import splat_object

GAUSSIAN_SPLAT = "GAUSSIAN_SPLAT"
# Blender attribute data type -> (foreach property, values per point, dtype). FLOAT4 (5.3) is what
# Blender writes for radiance:base; a FLOAT_COLOR of the same name is read the same way.
_KEYS = {"FLOAT_VECTOR": ("vector", 3, np.float32), "QUATERNION": ("value", 4, np.float32),
         "FLOAT4": ("vector", 4, np.float32), "FLOAT_COLOR": ("color", 4, np.float32),
         "FLOAT": ("value", 1, np.float32), "BOOLEAN": ("value", 1, np.bool_)}
HIDE = ".hide"  # hidden points, where this Blender's point cloud Edit Mode records them


class BlenderSplatsUnsupported(RuntimeError):
    """This Blender has no Gaussian splat point clouds (they came in 5.3)."""


def supported() -> bool:
    """This Blender has point clouds of type 'GAUSSIAN_SPLAT' (5.3 and later)."""
    prop = bpy.types.PointCloud.bl_rna.properties.get("type")
    return prop is not None and GAUSSIAN_SPLAT in prop.enum_items.keys()


def require_support() -> None:
    if not supported():
        raise BlenderSplatsUnsupported(
            f"Blender {bpy.app.version_string} has no Gaussian splat point clouds (Blender 5.3 "
            f"and later have them)")


def is_blender_splat_data(data) -> bool:
    return isinstance(data, bpy.types.PointCloud) and getattr(data, "type", None) == GAUSSIAN_SPLAT


def is_blender_splat_object(obj) -> bool:
    return obj is not None and obj.type == "POINTCLOUD" and is_blender_splat_data(obj.data)


def attribute_names(data) -> set[str]:
    return {a.name for a in data.attributes if a.domain == "POINT"}


def read_attribute(attribute, n: int) -> np.ndarray | None:
    """A point attribute's values (n, width), float32 (bool for a BOOLEAN), or None for a type
    we do not read."""
    spec = _KEYS.get(attribute.data_type)
    if spec is None:
        return None
    key, width, dtype = spec
    out = np.empty(n * width, dtype)
    if n:
        attribute.data.foreach_get(key, out)
    return out.reshape(n, width)


def point_count(data) -> int:
    position = data.attributes.get(attributes.POSITION)
    return len(position.data) if position is not None else 0


def hidden_mask(data) -> np.ndarray | None:
    """The points hidden in Edit Mode, None where none is."""
    attribute = data.attributes.get(HIDE)
    if attribute is None or attribute.domain != "POINT" or attribute.data_type != "BOOLEAN":
        return None
    hide = read_attribute(attribute, len(attribute.data))[:, 0]
    return hide if hide.any() else None


def degree_of(data) -> tuple[int, list[str]]:
    """The SH degree `data`'s attributes hold, and what is left out (`attributes.degree_of`)."""
    return attributes.degree_of(frozenset(attribute_names(data)))


def read_names(data) -> tuple[str, ...]:
    """The attributes `read_conversion` reads from `data` (for change detection)."""
    degree, _ = degree_of(data)
    return tuple(attributes.REQUIRED) + attributes.sh_names(
        min(degree, attributes.RENDER_MAX_DEGREE)) + (HIDE,)


def raw_log_scales(data) -> np.ndarray:
    """Per point, log of the `scale` attribute (NaN where it is not finite), for measures."""
    scale = read_attribute(data.attributes[attributes.SCALE], point_count(data))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.log(np.abs(scale.astype(np.float64))).astype(np.float32)


def raw_logits(data) -> np.ndarray:
    """Per point, the opacity logit of `radiance:base`.w (clamped as the convention reads it)."""
    base = read_attribute(data.attributes[attributes.BASE], point_count(data))
    return attributes.opacity_logits(base[:, 3])


def read_conversion(data, *, drop_hidden: bool = True) -> attributes.Conversion:
    """The object-space Gaussians a splat point cloud holds (see the attributes module for
    what is dropped and warned about). `BlenderSplatError` when an attribute is missing."""
    source = f"point cloud {data.name!r}"
    n = point_count(data)
    arrays: dict[str, np.ndarray] = {}
    for name in attribute_names(data):
        if name in attributes.REQUIRED or name.startswith(attributes.SH_PREFIX):
            attribute = data.attributes[name]
            values = read_attribute(attribute, n)
            if values is None or values.dtype != np.float32 or len(attribute.data) != n:
                raise attributes.BlenderSplatError(
                    f"{source}: attribute {name!r} is {attribute.data_type}, not "
                    f"{attributes.REQUIRED.get(name, attributes.SH_TYPE)[0]}")
            arrays[name] = values
    if drop_hidden:
        hide = hidden_mask(data)
        if hide is not None and len(hide) == n:
            arrays = {name: values[~hide] for name, values in arrays.items()}
    return attributes.gaussians_from_attributes(arrays, source=source)


def read_gaussians(data, *, drop_hidden: bool = True) -> Gaussians:
    return read_conversion(data, drop_hidden=drop_hidden).gaussians


# ------------------------------------------------------------------------------------ writing


def _sized_pointcloud(name: str, n: int):
    """A new PointCloud with `n` points: `PointCloud.resize` (5.3); before it, the object
    Convert operator turns a vertex-only mesh into one, keeping its point attributes."""
    if hasattr(bpy.types.PointCloud, "resize"):
        pointcloud = bpy.data.pointclouds.new(name)
        pointcloud.resize(n)
        return pointcloud
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(n)
    holder = bpy.data.objects.new(name, mesh)
    scene = bpy.context.scene
    scene.collection.objects.link(holder)
    try:
        with bpy.context.temp_override(object=holder, active_object=holder,
                                       selected_objects=[holder],
                                       selected_editable_objects=[holder]):
            bpy.ops.object.convert(target="POINTCLOUD", keep_original=False)
        if holder.type != "POINTCLOUD":
            raise RuntimeError(f"Blender could not make a point cloud of {n} points")
        pointcloud = holder.data
        pointcloud.name = name
        for leftover in [a.name for a in pointcloud.attributes if a.name.startswith(".select")]:
            pointcloud.attributes.remove(pointcloud.attributes[leftover])
        return pointcloud
    finally:
        bpy.data.objects.remove(holder)
        if mesh.users == 0 and mesh.name in bpy.data.meshes:
            bpy.data.meshes.remove(mesh)
        bpy.context.view_layer.update()  # no stale base of the holder in the layer's objects


def write_attributes(pointcloud, gaussians: Gaussians) -> None:
    """Write `gaussians` into `pointcloud` (which has one point per Gaussian) as Blender's
    splat attributes; `radiance:sh_*` beyond the Gaussians' degree are removed."""
    arrays = attributes.attributes_from_gaussians(gaussians)
    existing = pointcloud.attributes
    for name, values in arrays.items():
        data_type = attributes.REQUIRED.get(name, attributes.SH_TYPE)[0]
        attribute = existing.get(name)
        if attribute is not None and (attribute.data_type != data_type or attribute.domain != "POINT"):
            existing.remove(attribute)
            attribute = None
        if attribute is None:
            attribute = existing.new(name, data_type, "POINT")
        if len(values):
            attribute.data.foreach_set(_KEYS[data_type][0], np.ascontiguousarray(values).reshape(-1))
    for attribute in [a for a in existing if a.name.startswith(attributes.SH_PREFIX)
                      and a.name not in arrays]:
        existing.remove(attribute)
    pointcloud.update_tag()


def new_pointcloud(gaussians: Gaussians, name: str):
    """A new PointCloud of type GAUSSIAN_SPLAT holding `gaussians` (object space). Raises
    BlenderSplatsUnsupported before 5.3, ValueError for NaN or Inf; leaves nothing behind."""
    require_support()
    bad = gaussians.non_finite()
    if bad is not None:
        raise ValueError(f"Gaussians.{bad} holds NaN or Inf")
    pointcloud = _sized_pointcloud(name, len(gaussians))
    try:
        pointcloud.type = GAUSSIAN_SPLAT
        write_attributes(pointcloud, gaussians)
    except BaseException:
        bpy.data.pointclouds.remove(pointcloud)
        raise
    return pointcloud


def create_object(gaussians: Gaussians, name: str = "Splats", *, collection=None):
    """A new object holding a Blender splat point cloud of `gaussians` in its local space,
    linked to `collection` (the scene's master collection when None)."""
    pointcloud = new_pointcloud(gaussians, name)
    obj = splat_object.new_object(name, pointcloud, bpy.data.pointclouds)
    try:
        (collection or bpy.context.scene.collection).objects.link(obj)
    except BaseException:
        bpy.data.objects.remove(obj)
        bpy.data.pointclouds.remove(pointcloud)
        raise
    return obj


# ------------------------------------------------------------------- changing the point count

# data type -> (foreach property, values per point, numpy dtype): every point attribute a
# point cloud can hold that is copied exactly when points are removed
_GENERIC = {
    "FLOAT": ("value", 1, np.float32), "INT": ("value", 1, np.int32),
    "BOOLEAN": ("value", 1, bool), "FLOAT_VECTOR": ("vector", 3, np.float32),
    "FLOAT2": ("vector", 2, np.float32), "QUATERNION": ("value", 4, np.float32),
    "FLOAT4": ("vector", 4, np.float32), "FLOAT_COLOR": ("color", 4, np.float32),
    "BYTE_COLOR": ("color", 4, np.float32), "INT8": ("value", 1, np.int32),
    "INT32_2D": ("value", 2, np.int32), "INT16_2D": ("value", 2, np.int32),
    "FLOAT4X4": ("value", 16, np.float32),
}


def _swap_data(obj, pointcloud) -> None:
    """Give `obj` the new point cloud `pointcloud` in place of its own (same name, type and
    materials); the old one is removed when nothing else uses it."""
    old = obj.data
    for material in old.materials:
        pointcloud.materials.append(material)
    name = old.name
    obj.data = pointcloud
    if old.users == 0:
        bpy.data.pointclouds.remove(old)
    pointcloud.name = name


def remove_points(obj, keep: np.ndarray) -> int:
    """Delete the points of `obj`'s point cloud where `keep` is False, keeping every point
    attribute of the others (copied exactly). Python cannot shrink a point cloud, so a new one
    with the kept points replaces it. Returns how many were removed."""
    old = obj.data
    n = point_count(old)
    keep = np.asarray(keep, bool)
    if keep.shape != (n,):
        raise ValueError(f"keep mask has shape {keep.shape}, point cloud has {n} points")
    removed = int(n - np.count_nonzero(keep))
    if removed == 0:
        return 0
    saved = []
    for attribute in old.attributes:
        spec = _GENERIC.get(attribute.data_type)
        if attribute.domain != "POINT" or spec is None or attribute.name == attributes.POSITION:
            continue
        key, width, dtype = spec
        values = np.empty(n * width, dtype)
        if n:
            attribute.data.foreach_get(key, values)
        saved.append((attribute.name, attribute.data_type, key, values.reshape(n, width)[keep]))
    positions = np.empty(n * 3, np.float32)
    if n:
        old.attributes[attributes.POSITION].data.foreach_get("vector", positions)
    pointcloud = _sized_pointcloud(old.name, n - removed)
    try:
        if hasattr(old, "type"):
            pointcloud.type = old.type
        if n - removed:
            pointcloud.attributes[attributes.POSITION].data.foreach_set(
                "vector", positions.reshape(n, 3)[keep].reshape(-1))
        for name, data_type, key, values in saved:
            attribute = pointcloud.attributes.get(name) or pointcloud.attributes.new(
                name, data_type, "POINT")
            if len(values):
                attribute.data.foreach_set(key, np.ascontiguousarray(values).reshape(-1))
    except BaseException:
        bpy.data.pointclouds.remove(pointcloud)
        raise
    _swap_data(obj, pointcloud)
    return removed


def replace_gaussians(obj, gaussians: Gaussians) -> None:
    """Rewrite a Blender splat object's point cloud with `gaussians` (any count)."""
    if point_count(obj.data) == len(gaussians) and gaussians.non_finite() is None:
        if len(gaussians):
            obj.data.attributes[attributes.POSITION].data.foreach_set(
                "vector", gaussians.means.reshape(-1))
        write_attributes(obj.data, gaussians)
        return
    _swap_data(obj, new_pointcloud(gaussians, obj.data.name))


SELECTION = ".selection"  # selected points (point cloud Edit Mode)


def selection(data) -> np.ndarray:
    n = point_count(data)
    out = np.zeros(n, bool)
    attribute = data.attributes.get(SELECTION)
    if attribute is not None and attribute.domain == "POINT" and n:
        if attribute.data_type == "BOOLEAN":
            attribute.data.foreach_get("value", out)
        elif attribute.data_type == "FLOAT":
            values = np.empty(n, np.float32)
            attribute.data.foreach_get("value", values)
            out = values > 0
    return out


def set_selection(data, selected: np.ndarray) -> None:
    attribute = data.attributes.get(SELECTION)
    if attribute is not None and (attribute.domain != "POINT" or attribute.data_type != "BOOLEAN"):
        data.attributes.remove(attribute)
        attribute = None
    if attribute is None:
        attribute = data.attributes.new(SELECTION, "BOOLEAN", "POINT")
    if len(selected):
        attribute.data.foreach_set("value", np.asarray(selected, bool))
    data.update_tag()
