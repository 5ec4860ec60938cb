"""Splat objects of either kind, for the features that take both: the add-on's own (a mesh with
its splat attributes, `splat_object`) and Blender 5.3's (a point cloud of type
'GAUSSIAN_SPLAT', `blender_splats.data`). Each function picks the kind's own code."""

from __future__ import annotations

import numpy as np

from ...core.gaussians import Gaussians
from .. import splat_object
from . import data


def is_splat_source(obj) -> bool:
    """An add-on splat object or a Blender splat point cloud object."""
    return splat_object.is_splat_object(obj) or data.is_blender_splat_object(obj)


def data_gaussians(geometry, *, drop_hidden: bool = True) -> Gaussians:
    """The object-space Gaussians of a Mesh or PointCloud (original or evaluated) of either
    kind; SplatDataError / BlenderSplatError (both ValueError) when it holds none."""
    if data.is_blender_splat_data(geometry):
        return data.read_gaussians(geometry, drop_hidden=drop_hidden)
    return splat_object.gaussians_from_data(geometry, drop_hidden=drop_hidden)


def object_gaussians(obj, *, drop_hidden: bool = True) -> Gaussians:
    """The object-space Gaussians of `obj`'s own (original) data."""
    return data_gaussians(obj.data, drop_hidden=drop_hidden)


def point_count(obj) -> int:
    return splat_object.point_count(obj.data)


def remove_points(obj, keep: np.ndarray) -> int:
    """Delete the splats where `keep` is False (Object Mode), keeping every other attribute."""
    if data.is_blender_splat_object(obj):
        return data.remove_points(obj, keep)
    return splat_object.remove_points(obj, keep)


def replace_gaussians(obj, gaussians: Gaussians) -> None:
    """Rewrite the object's splats with `gaussians` (any count), keeping its kind."""
    if data.is_blender_splat_object(obj):
        data.replace_gaussians(obj, gaussians)
    else:
        splat_object.replace_gaussians(obj, gaussians)


def selection(obj) -> np.ndarray:
    if data.is_blender_splat_object(obj):
        return data.selection(obj.data)
    mesh = obj.data
    out = np.zeros(len(mesh.vertices), bool)
    if len(out):
        mesh.vertices.foreach_get("select", out)
    return out


def set_selection(obj, selected: np.ndarray) -> None:
    if data.is_blender_splat_object(obj):
        data.set_selection(obj.data, selected)
        return
    if len(selected):
        obj.data.vertices.foreach_set("select", np.asarray(selected, bool))
    obj.data.update()


def hidden(obj) -> np.ndarray:
    mask = (data.hidden_mask(obj.data) if data.is_blender_splat_object(obj)
            else splat_object.hidden_mask(obj.data))
    return np.zeros(point_count(obj), bool) if mask is None else mask
