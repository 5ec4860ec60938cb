"""Blender 5.3's own splat point cloud (type 'GAUSSIAN_SPLAT'; `blender_splats.data` reads it,
`core.blender_splats.attributes` holds the convention). One the add-on renders through its
empty render modifier is read from its own data (`ownership.reads_original`: a render
evaluates it empty); one handed back to Blender's renderer (`Object.splat.render_by_blender`)
is no source unless export asks for it.

One with modifiers of its own (geometry nodes that set positions, and whatever else this
Blender lets deform a point cloud) is read evaluated, and its Gaussians' shapes and SH follow
the deformation as the add-on's objects' do (`deformed.Deformable`: the original cloud's
positions are the rest ones)."""

from __future__ import annotations

import numpy as np

from ...core.blender_splats import attributes
from ...core.gaussians import Gaussians
from .. import splat_object
from ..blender_splats import data as blender_data
from ..blender_splats import ownership
from .base import settings_of
from .deformed import Deformable


def _blender_renders(evaluated, owner) -> bool:
    """A Blender splat point cloud handed back to Blender's own renderer (per object)."""
    for candidate in (evaluated.original, owner):
        if blender_data.is_blender_splat_object(candidate):
            return bool(candidate.splat.render_by_blender)
    return False


class BlenderCloud(Deformable):
    kind = "Blender splat point cloud"

    @classmethod
    def of(cls, instance, evaluated, owner, include_blender_rendered: bool = False):
        """The source of an evaluated Blender splat point cloud; None when Blender renders it
        (unless `include_blender_rendered`)."""
        data = evaluated.data
        if ownership.reads_original(evaluated.original):
            data = evaluated.original.data  # a render evaluates it empty (ownership module)
        if not include_blender_rendered and _blender_renders(evaluated, owner):
            return None
        source_degree, notes = blender_data.degree_of(data)
        settings = settings_of(evaluated, owner, blender_data.is_blender_splat_object,
                               splat_object.is_splat_object)
        return cls(instance, evaluated, owner, data,
                   min(source_degree, attributes.RENDER_MAX_DEGREE),
                   blender_data.read_names(data), settings, tuple(notes))

    def point_count(self) -> int:
        return blender_data.point_count(self.data)

    def _holds_splats(self, data) -> bool:
        return blender_data.is_blender_splat_data(data)

    def _gaussians(self, warnings: list[str], drop_hidden: bool
                   ) -> tuple[Gaussians, np.ndarray | None]:
        conversion = blender_data.read_conversion(self.data, drop_hidden=drop_hidden)
        warnings.extend(w for w in conversion.warnings if w not in warnings and "degree" not in w)
        return conversion.gaussians, conversion.kept

    def _hidden(self) -> np.ndarray | None:
        return blender_data.hidden_mask(self.data)
