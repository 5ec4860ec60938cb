"""Where a frame's splats come from: one source per kind of splat object, each answering the
same questions, and `gather`, which asks every one a depsgraph shows.

A source (`base.Source`) is one instance of a splat geometry in an evaluated depsgraph. Every
kind answers:

    read(warnings)   its Gaussians in object space (SH bands as the data holds them, hidden
                     splats left out)
    matrix(space)    the matrix to render them with (the instance's world matrix, taken by
                     export's axis conversion `space`)
    change_key()     what changes when its Gaussians may have (None: ask every time), and
                     contents() what they are (a checksum), for the gather cache
    its display      `shown` (the viewport draws it) and its render options: `antialiased`,
                     `color_space`, `sh_degree()` (from `settings`, the object's `obj.splat`)

The kinds:

    own.OwnObject           the add-on's splat object (a mesh, or a point cloud, holding its
                            splat attributes); a splat sequence's frame is one too: io/sequence.py
                            rewrites the object's mesh before Blender evaluates the frame
    edit_mesh.EditMesh      the add-on's object in Edit Mode (its evaluated mesh wraps the edit
                            BMesh: read through `to_mesh`, hidden flags from the BMesh, no key)
    blender_cloud.BlenderCloud  Blender 5.3's own splat point cloud (type 'GAUSSIAN_SPLAT'),
                            unless handed back to Blender's renderer
    deformed.Deformable     what the two kinds that read evaluated points share: their
                            Gaussians' shapes and SH follow a deform stack (one rule: the
                            stack moved the points and kept their count)
    live.LiveSnapshot       either kind's Gaussians while a running job shows its snapshots
                            in their place (training's updates, without writing the data)

`source_of(instance, ...)` picks the kind; `gather.gather(depsgraph)` transforms, batches and
caches what they answer.
"""

from __future__ import annotations

from .. import splat_object
from ..blender_splats import data as blender_data
from .base import Source
from .blender_cloud import BlenderCloud
from .edit_mesh import EditMesh
from .live import LiveSnapshot
from .own import OwnObject

__all__ = ["BlenderCloud", "EditMesh", "LiveSnapshot", "OwnObject", "Source", "source_of"]


def source_of(instance, *, wanted: set[int] | None = None,
              include_blender_rendered: bool = False) -> Source | None:
    """The source of a depsgraph object instance, or None: not splats, not one of `wanted`
    (original objects' `session_uid`s: the object or the instancer), or handed to Blender."""
    evaluated = instance.object
    if evaluated.type not in ("MESH", "POINTCLOUD"):
        return None
    owner = (instance.parent.original if instance.is_instance and instance.parent is not None
             else evaluated.original)
    if wanted is not None and owner.session_uid not in wanted \
            and evaluated.original.session_uid not in wanted:
        return None
    snapshot = LiveSnapshot.of(instance, evaluated, owner, splat_object.is_splat_object,
                               blender_data.is_blender_splat_object)
    if snapshot is not None:
        return snapshot
    if evaluated.type == "POINTCLOUD" and blender_data.is_blender_splat_data(evaluated.data):
        return BlenderCloud.of(instance, evaluated, owner, include_blender_rendered)
    kind = EditMesh if evaluated.type == "MESH" and evaluated.data.is_editmode else OwnObject
    return kind.of(instance, evaluated, owner)
