"""The add-on's splat object in Edit Mode: its evaluated mesh is a wrapper around the edit
BMesh, so it is read through `to_mesh`, its hidden flags (which live on the BMesh only) from
the BMesh. It has no change key: `gather` reads it every time and hands out the Gaussians it
gave last while they read the same."""

from __future__ import annotations

import numpy as np

from ...core.gaussians import Gaussians
from .. import splat_object
from .own import OwnObject


def _edit_mode_hidden(mesh) -> np.ndarray | None:
    import bmesh

    try:
        bm = bmesh.from_edit_mesh(mesh)
    except (ValueError, RuntimeError):
        return None
    hide = np.fromiter((v.hide for v in bm.verts), bool, count=len(bm.verts))
    return hide if hide.any() else None


def edit_mode_gaussians(evaluated) -> Gaussians:
    """The splats of an evaluated mesh object in Edit Mode, hidden vertices dropped. Its
    evaluated mesh is a wrapper around the edit BMesh; `to_mesh` makes it real. Hidden flags
    live on the BMesh only."""
    mesh = evaluated.to_mesh()  # (preserve_all_data_layers=True would re-evaluate the stale original)
    try:
        gaussians = splat_object.gaussians_from_data(mesh, drop_hidden=False)
    finally:
        evaluated.to_mesh_clear()
    hide = _edit_mode_hidden(evaluated.original.data)
    if hide is not None and len(hide) == len(gaussians):
        gaussians = gaussians.subset(~hide)
    return gaussians


class EditMesh(OwnObject):
    kind = "splat object in Edit Mode"
    keyed = False

    def change_key(self) -> None:
        return None

    def read(self, warnings: list[str]) -> Gaussians:
        return edit_mode_gaussians(self.evaluated)
