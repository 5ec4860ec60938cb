"""The add-on's own splat object: a mesh (or a point cloud) holding its splat attributes
(`splat_object`), read with `foreach_get`, vertices hidden in Edit Mode left out.

A deform stack (modifiers: armature, lattice, simple deform, hook, cast, warp, wave, mesh
deform, geometry nodes that keep the points...; shape keys; a legacy armature, lattice or curve
parent) moves the vertices, which are the Gaussians' centres, and passes every other attribute
through as stored. When the evaluated geometry has the original's point count and its centres
moved, each Gaussian's shape and SH follow the deformation too (`core.deform`: the Jacobian at
its centre from its neighbours, rest positions read from the original data, their neighbour
lists cached while those stay the same), the object's matrix folded into that one pass
(`read_world`: each SH turned once, not for the deformation and again by the gather). An object
with none of these reads as it always did, at no extra cost; one whose stack moves nothing costs
one comparison of the positions.

A splat sequence's frame is one of these: `io/sequence.py` rewrites the object's mesh with the
frame's file before Blender evaluates the frame, so its key and contents follow the frame."""

from __future__ import annotations

import numpy as np

from ...core import native
from ...core.deform import RestNeighbours, deform
from ...core.gaussians import Gaussians
from ...core.transform import transform_gaussians
from .. import splat_object
from ..blender_splats import data as blender_data
from .base import Source, settings_of

# Parent types that deform the child's geometry without a modifier (Blender's legacy
# "virtual modifiers").
_DEFORMING_PARENTS = frozenset({"ARMATURE", "LATTICE", "CURVE"})

_neighbours = RestNeighbours()  # by original object: its rest positions' neighbour lists


def clear_neighbours() -> None:
    _neighbours.clear()


def _positions(data) -> np.ndarray:
    n = splat_object.point_count(data)
    out = np.empty(n * 3, np.float32)
    if n:
        data.attributes[splat_object.POSITION].data.foreach_get("vector", out)
    return out.reshape(n, 3)


def may_deform(original) -> bool:
    """Whether anything may move the object's points: modifiers, shape keys, a deforming
    parent. False costs nothing more than these three looks."""
    return bool(original.modifiers) or getattr(original.data, "shape_keys", None) is not None \
        or (original.parent is not None and original.parent_type in _DEFORMING_PARENTS)


class OwnObject(Source):
    kind = "splat object"

    @classmethod
    def of(cls, instance, evaluated, owner):
        """The source of an evaluated Mesh or PointCloud holding the add-on's splat attributes;
        None when it holds none."""
        data = evaluated.data
        degree = splat_object.data_sh_degree(data)
        if degree is None:
            return None
        names = (splat_object.POSITION, splat_object.ROTATION, splat_object.LOG_SCALE,
                 splat_object.OPACITY_LOGIT, splat_object.HIDE) + splat_object.SH_NAMES[
                     :(degree + 1) ** 2]
        settings = settings_of(evaluated, owner, splat_object.is_splat_object,
                               blender_data.is_blender_splat_object)
        return cls(instance, evaluated, owner, data, degree, names, settings)

    def point_count(self) -> int:
        return splat_object.point_count(self.data)

    def rest_data(self):
        """The original data the evaluated points were deformed from, or None: nothing may
        deform them, the evaluated data is the original, or the point count changed (then
        the points are not the original's, moved)."""
        original = self.evaluated.original
        if original is None or not may_deform(original):
            return None
        rest = original.data
        if rest is None or rest == self.data or rest.as_pointer() == self.data.as_pointer() \
                or splat_object.data_sh_degree(rest) is None \
                or splat_object.point_count(rest) != self.point_count():
            return None
        return rest

    def contents(self) -> tuple:
        """The evaluated attributes' checksum, and the rest positions' when the shapes follow
        a deformation (the same deformed centres from other rest ones bend differently)."""
        own = super().contents()
        rest = self.rest_data()
        return own if rest is None else (own, native.checksum(_positions(rest)))

    def read(self, warnings: list[str]) -> Gaussians:
        return self._read(None, None)

    def read_world(self, matrix: np.ndarray, sh_degree: int,
                   warnings: list[str]) -> Gaussians | None:
        """Deformed: the object's matrix folded into the deformation's one pass (each SH
        turned once, not for the deformation and again for the object); else None (read, then
        transform, as any source)."""
        if self.rest_data() is None:
            return None
        return self._read(matrix, sh_degree)

    def _read(self, matrix: np.ndarray | None, sh_degree: int | None) -> Gaussians:
        gaussians = splat_object.gaussians_from_data(self.data, drop_hidden=False)
        if sh_degree is not None and sh_degree < gaussians.degree:
            gaussians = gaussians.with_degree(sh_degree)
        rest_data = self.rest_data()
        deformed = False
        if rest_data is not None:
            rest = _positions(rest_data)
            if not np.array_equal(rest, gaussians.means):
                hoods = _neighbours.get(self.evaluated.original.session_uid, rest)
                # over a fresh read no one else holds
                gaussians = deform(gaussians, hoods, matrix=matrix, in_place=True)
                deformed = True
        if matrix is not None and not deformed:
            gaussians = transform_gaussians(gaussians, matrix)
        hide = splat_object.hidden_mask(self.data)
        if hide is not None and len(hide) == len(gaussians):
            gaussians = gaussians.subset(~hide)
        return gaussians
