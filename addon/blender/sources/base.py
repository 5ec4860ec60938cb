"""What every kind of splat source answers alike: who it is, its settings, the matrix to render
with, its change key and a checksum of its contents (see the package docstring).

The change key of a keyed source: update counters of the original object, its data and the
instancer (bumped by `gather`'s `depsgraph_update_post` handler through `bump` for every ID the
depsgraph reports with `is_updated_geometry`: edits, modifiers, geometry nodes, Edit Mode
changes, undo), plus the data's address, its point count and the addresses of the attribute
arrays the Gaussians are read from (these catch changes made through a depsgraph whose updates
run no handler, such as a render's own depsgraph). `contents()` is what decides when the key
misses: a checksum of those attributes.
"""

from __future__ import annotations

import ctypes

import numpy as np

from ...core import native
from ...core.axes import snap
from ...core.gaussians import Gaussians

_generations: dict[int, int] = {}


def bump(uid: int) -> None:
    """An ID (by `session_uid`) changed its geometry: keys that name it change."""
    _generations[uid] = _generations.get(uid, 0) + 1


def _generation(id_data) -> int:
    return 0 if id_data is None else _generations.get(id_data.session_uid, 0)


def _attribute_addresses(data, names: tuple[str, ...]) -> tuple:
    attributes = data.attributes
    addresses = []
    for name in names:
        attribute = attributes.get(name)
        addresses.append(attribute.data[0].as_pointer()
                         if attribute is not None and len(attribute.data) else 0)
    return tuple(addresses)


# Attribute data type -> (foreach_get property, values per point, dtype).
_RAW = {"FLOAT_VECTOR": ("vector", 3, np.float32), "QUATERNION": ("value", 4, np.float32),
        "FLOAT": ("value", 1, np.float32), "BOOLEAN": ("value", 1, np.bool_),
        "FLOAT4": ("vector", 4, np.float32), "FLOAT_COLOR": ("color", 4, np.float32)}


def _stored_values(attribute, count: int, stride: int):
    """The attribute's values where Blender keeps them (a buffer over its array, no copy), when
    its elements lie `stride` bytes apart from the first to the last; else None."""
    if count == 0:
        return b""
    first = attribute.data[0].as_pointer()
    if first == 0 or attribute.data[count - 1].as_pointer() - first != (count - 1) * stride:
        return None
    return (ctypes.c_char * (count * stride)).from_address(first)


def contents(data, names: tuple[str, ...]) -> tuple:
    """A checksum of what a source reads from `data` (the `names` attributes: the splat
    attributes and the hidden flags): per attribute its type, domain and size, and
    `splatcore.checksum` of its values, read where Blender stores them (through `foreach_get`
    when they are not one array). A change within any 193 consecutive bits of an attribute (one
    value, or a few neighbouring ones) always changes its checksum; any other change goes
    unnoticed only if four 64-bit sums all come out the same."""
    checksum = native.checksum
    attributes = data.attributes
    sums, shapes = [], []
    for name in names:
        attribute = attributes.get(name)
        raw = None if attribute is None else _RAW.get(attribute.data_type)
        if raw is None:
            shapes.append(None if attribute is None else (attribute.data_type, attribute.domain))
            continue
        key, width, dtype = raw
        count = len(attribute.data)
        values = _stored_values(attribute, count, width * np.dtype(dtype).itemsize)
        if values is None:
            values = np.empty(count * width, dtype)
            if count:
                attribute.data.foreach_get(key, values)
        sums.append(checksum(values))
        shapes.append((attribute.data_type, attribute.domain, count * width))
    return tuple(shapes), tuple(sums)


class Source:
    """One instance of a splat geometry in an evaluated depsgraph (a kind subclasses it).

    `instance` is the depsgraph's object instance, `evaluated` its evaluated object, `owner`
    the original object the splats belong to (the instancer for an instance, else the object),
    `data` the geometry read from, `degree` the SH degree it holds (at most the renderer's 3),
    `names` the attributes read (and checksummed), `notes` what the data leaves out."""

    kind = ""
    keyed = True   # whether `change_key` can tell an unchanged source (Edit Mode's cannot)

    def __init__(self, instance, evaluated, owner, data, degree: int, names: tuple[str, ...],
                 settings, notes: tuple[str, ...] = ()) -> None:
        self.instance, self.evaluated, self.owner, self.data = instance, evaluated, owner, data
        self.degree, self.names, self.settings, self.notes = degree, names, settings, notes
        # who it is: original object, owner, `persistent_id`, geometry type
        self.identity = (evaluated.original.session_uid, owner.session_uid,
                         tuple(instance.persistent_id) if instance.is_instance else None,
                         evaluated.type)

    # -- how it is shown and rendered

    def sh_degree(self, all_sh_bands: bool = False) -> int:
        """The SH degree to render: the object's option, at most what the data holds."""
        if self.settings is None or all_sh_bands:
            return self.degree
        return min(self.settings.sh_degree, self.degree)

    @property
    def antialiased(self) -> bool:
        return False if self.settings is None else self.settings.antialiased

    @property
    def color_space(self) -> str:
        return "SRGB" if self.settings is None else self.settings.color_space

    @property
    def shown(self) -> bool:
        """Whether the viewport draws it: its owner's "Show in Viewport" (the scene's own switch
        is the viewport's to read)."""
        settings = getattr(self.owner, "splat", None)
        return settings is None or getattr(settings, "show_in_viewport", True)

    # -- where it is, whether it changed, what it holds

    def matrix(self, space: np.ndarray | None = None) -> np.ndarray:
        """(4, 4) float64: the instance's world matrix, then `space` (snapped: an import's axis
        conversion undone comes back as the exact identity)."""
        matrix = np.array(self.instance.matrix_world, dtype=np.float64)
        return matrix if space is None else snap(space @ matrix)

    def change_key(self) -> tuple | None:
        """Equal while the Gaussians cannot have changed (see the module docstring); None for a
        source that cannot tell (`keyed` False)."""
        original = self.evaluated.original
        return (_generation(original), _generation(original.data), _generation(self.owner),
                self.data.as_pointer(), self.point_count(), _attribute_addresses(self.data,
                                                                                 self.names))

    def contents(self) -> tuple:
        return contents(self.data, self.names)

    def point_count(self) -> int:
        raise NotImplementedError

    def read(self, warnings: list[str]) -> Gaussians:
        """Its Gaussians in object space, every SH band the data holds, hidden splats left
        out; what the reading leaves out is added to `warnings`."""
        raise NotImplementedError

    def read_world(self, matrix: np.ndarray, sh_degree: int,
                   warnings: list[str]) -> Gaussians | None:
        """Its Gaussians taken by `matrix` (4x4) and cut to `sh_degree` in one step, for a
        source that does that for less than `read` then `transform_gaussians` (a deformed
        splat object or cloud turns each SH once); None: read, then transform."""
        return None


def settings_of(evaluated, owner, is_one, or_one):
    """`obj.splat` of the splat object the geometry belongs to: the evaluated object's original
    when it is one (`is_one` or `or_one`: the kind's own test first), else the owner (the
    instancer); None: defaults."""
    for candidate in (evaluated.original, owner):
        if is_one(candidate) or or_one(candidate):
            return candidate.splat
    return None
