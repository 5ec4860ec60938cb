"""The add-on's own splat object: a mesh (or a point cloud) holding its splat attributes
(`splat_object`), read with `foreach_get`, vertices hidden in Edit Mode left out.

A deform stack (modifiers, shape keys, a deforming parent) bends its Gaussians' shapes and SH,
not only their centres, by the rule every such kind shares (`deformed.Deformable`).

A splat sequence's frame is one of these: `io/sequence.py` rewrites the object's mesh with the
frame's file before Blender evaluates the frame, so its key and contents follow the frame."""

from __future__ import annotations

import numpy as np

from ...core.gaussians import Gaussians
from .. import splat_object
from ..blender_splats import data as blender_data
from .base import settings_of
from .deformed import Deformable


class OwnObject(Deformable):
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

    def _holds_splats(self, data) -> bool:
        return splat_object.data_sh_degree(data) is not None

    def _gaussians(self, warnings: list[str], drop_hidden: bool
                   ) -> tuple[Gaussians, np.ndarray | None]:
        return splat_object.gaussians_from_data(self.data, drop_hidden=drop_hidden), None

    def _hidden(self) -> np.ndarray | None:
        return splat_object.hidden_mask(self.data)
