"""Splats that follow their object's deform stack: the one rule for every kind of source whose
evaluated points may be its original data's points, moved (the add-on's object, `own`;
Blender 5.3's splat point cloud, `blender_cloud`).

A deform stack (modifiers: armature, lattice, simple deform, hook, cast, warp, wave, mesh
deform, geometry nodes that keep the points...; shape keys; a legacy armature, lattice or curve
parent) moves the points, which are the Gaussians' centres, and passes every other attribute
through as stored. When the evaluated geometry has the original's point count and its centres
moved, each Gaussian's shape and SH follow the deformation too (`core.deform`: the Jacobian at
its centre from its neighbours, rest positions read from the original data, their neighbour
lists cached while those stay the same), the object's matrix folded into that one pass
(`read_world`: each SH turned once, not for the deformation and again by the gather). An object
with none of these reads as it always did, at no extra cost; one whose stack moves nothing costs
one comparison of the positions. The gather's cache keeps a deformed source's Gaussians while
its evaluated attributes and rest positions read the same (`contents`): a frame whose
deformation did not change recomputes nothing.

A kind says how it reads its data (`_gaussians`), which points are hidden (`_hidden`) and
whether an original data holds its splats (`_holds_splats`); both keep the centres in
`position`.
"""

from __future__ import annotations

import numpy as np

from ...core import native
from ...core.deform import RestNeighbours, deform
from ...core.gaussians import Gaussians
from ...core.transform import transform_gaussians
from .base import Source

POSITION = "position"  # where both kinds keep the centres (the point clouds' and meshes' own)

# Parent types that deform the child's geometry without a modifier (Blender's legacy
# "virtual modifiers").
_DEFORMING_PARENTS = frozenset({"ARMATURE", "LATTICE", "CURVE"})

_neighbours = RestNeighbours()  # by original object: its rest positions' neighbour lists


def clear() -> None:
    """Forget every object's neighbour lists (a file loads, the gather cache is emptied)."""
    _neighbours.clear()


def point_count(data) -> int:
    position = data.attributes.get(POSITION)
    return len(position.data) if position is not None else 0


def positions(data) -> np.ndarray:
    """(N, 3) float32: the centres `data` holds."""
    n = point_count(data)
    out = np.empty(n * 3, np.float32)
    if n:
        data.attributes[POSITION].data.foreach_get("vector", out)
    return out.reshape(n, 3)


def may_deform(original) -> bool:
    """Whether anything may move the object's points: modifiers, shape keys, a deforming
    parent. False costs nothing more than these three looks."""
    return bool(original.modifiers) or getattr(original.data, "shape_keys", None) is not None \
        or (original.parent is not None and original.parent_type in _DEFORMING_PARENTS)


class Deformable(Source):
    """A source that reads evaluated points which a deform stack may have moved from its
    original data's (see the module docstring)."""

    # -- what a kind answers

    def _holds_splats(self, data) -> bool:
        """Whether `data` (the original object's) holds this kind's splat attributes."""
        raise NotImplementedError

    def _gaussians(self, warnings: list[str], drop_hidden: bool
                   ) -> tuple[Gaussians, np.ndarray | None]:
        """The data's Gaussians (object space, every SH band it holds; hidden points left out
        when `drop_hidden`), and which of its points they are ((N,) bool, None: all of them;
        a kind may leave out points it cannot read)."""
        raise NotImplementedError

    def _hidden(self) -> np.ndarray | None:
        """The data's hidden points ((N,) bool over all of them), None where none is."""
        raise NotImplementedError

    # -- the rule

    def rest_data(self):
        """The original data the evaluated points were deformed from, or None: nothing may
        deform them, the evaluated data is the original, or the point count changed (then
        the points are not the original's, moved)."""
        original = self.evaluated.original
        if original is None or not may_deform(original):
            return None
        rest = original.data
        if rest is None or rest == self.data or rest.as_pointer() == self.data.as_pointer() \
                or not self._holds_splats(rest) or point_count(rest) != self.point_count():
            return None
        return rest

    def contents(self) -> tuple:
        """The evaluated attributes' checksum, and the rest positions' when the shapes follow
        a deformation (the same deformed centres from other rest ones bend differently)."""
        own = super().contents()
        rest = self.rest_data()
        return own if rest is None else (own, native.checksum(positions(rest)))

    def read(self, warnings: list[str]) -> Gaussians:
        return self._read(None, None, warnings)

    def read_world(self, matrix: np.ndarray, sh_degree: int,
                   warnings: list[str]) -> Gaussians | None:
        """Deformed: the object's matrix folded into the deformation's one pass (each SH
        turned once, not for the deformation and again for the object); else None (read, then
        transform, as any source)."""
        if self.rest_data() is None:
            return None
        return self._read(matrix, sh_degree, warnings)

    def _read(self, matrix: np.ndarray | None, sh_degree: int | None,
              warnings: list[str]) -> Gaussians:
        rest_data = self.rest_data()
        if rest_data is None:
            gaussians, _ = self._gaussians(warnings, drop_hidden=True)
            if sh_degree is not None and sh_degree < gaussians.degree:
                gaussians = gaussians.with_degree(sh_degree)
            return gaussians if matrix is None else transform_gaussians(gaussians, matrix)
        gaussians, kept = self._gaussians(warnings, drop_hidden=False)
        if sh_degree is not None and sh_degree < gaussians.degree:
            gaussians = gaussians.with_degree(sh_degree)
        rest = positions(rest_data)
        if kept is not None:
            rest = np.ascontiguousarray(rest[kept])
        deformed = False
        if not np.array_equal(rest, gaussians.means):
            if np.isfinite(rest).all():
                hoods = _neighbours.get(self.evaluated.original.session_uid, rest)
                # over a fresh read no one else holds
                gaussians = deform(gaussians, hoods, matrix=matrix, in_place=True)
                deformed = True
            else:
                note = (f"{self.owner.name}: rest positions hold NaN or Inf: the splats' "
                        f"shapes do not follow the deformation")
                if note not in warnings:
                    warnings.append(note)
        if matrix is not None and not deformed:
            gaussians = transform_gaussians(gaussians, matrix)
        hide = self._hidden()
        if hide is not None and kept is not None and len(hide) == len(kept):
            hide = hide[kept]
        if hide is not None and len(hide) == len(gaussians):
            gaussians = gaussians.subset(~hide)
        return gaussians
