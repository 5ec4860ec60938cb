"""Gather the splats a depsgraph shows, in world space, ready for `addon.core.render.renderer.render`.

`gather(depsgraph)` walks `depsgraph.object_instances` (so it sees exactly what Blender would
render: visibility, modifiers, geometry nodes, instancing, parenting, constraints, drivers and
animation at the depsgraph's frame are all already applied) and, for every evaluated Mesh or
PointCloud that carries the splat attributes (see `splat_object`), reads them with
`foreach_get`, drops vertices hidden in Edit Mode, limits the SH bands to the object's
`sh_degree` option and transforms everything by the instance's world matrix with
`addon.core.transform.transform_gaussians` (centres, rotations, scales and SH bands 1-3; a
non-uniform scale re-decomposes each covariance exactly and rotates the SH by the polar
rotation). Render options come from the splat object the geometry belongs to: the evaluated
object itself when it is a splat object, else the instancer (`obj.splat`), else the defaults.

`objects=[...]` limits the gather to those objects and to the instances they make (export).

Cache: each instance's world-space Gaussians are kept, keyed by
  - the instance identity: original object, instancer, `persistent_id`, geometry type;
  - a geometry fingerprint: update counters of the original object, its data and the instancer,
    bumped by a `depsgraph_update_post` handler for every ID the depsgraph reports with
    `is_updated_geometry` (edits, modifiers, geometry nodes, Edit Mode changes, undo), plus the
    addresses of the evaluated attribute arrays and the point count (these catch changes made
    through a depsgraph whose updates run no handler, such as a render's own depsgraph);
  - the world matrix (exact bytes) and the SH degree used.
A moved object re-transforms; a changed geometry is read again; anything unchanged costs a
dictionary lookup. When that fingerprint misses (every final render evaluates a new depsgraph,
so its addresses are new, and a script may edit data in place with no handler running), a
checksum of the attribute contents (`splatcore.checksum` of every attribute the Gaussians are
read from, read in place: about 2.5 ms for 125k SH-2 splats, where a CRC-32 of `foreach_get`
copies took 6 to 7) decides: the same contents, the same world matrix
and SH degree reuse the transformed Gaussians (F12 again, the frames of an animation), anything
else reads and transforms again. The concatenation of all batches is cached the same way (a single batch is
returned as is). Objects in Edit Mode are never cached (their evaluated data is a BMesh
wrapper). `clear_cache()` empties everything; loading a file does it too. Returned arrays are
shared with the cache: treat them as read-only.
"""

from __future__ import annotations

import ctypes
import time
from dataclasses import dataclass, field

import bpy
import numpy as np
from bpy.app.handlers import persistent

from ..core import native
from ..core.axes import snap
from ..core.gaussians import Gaussians
from ..core.transform import transform_gaussians
from ..core.blender_splats import attributes
from . import splat_object
from .blender_splats import data as blender_data
from .blender_splats import ownership

_generations: dict[int, int] = {}
_world_cache: dict[tuple, tuple[tuple, Gaussians, tuple]] = {}  # key, world, contents
_combined_cache: dict[str, tuple[tuple, Gaussians]] = {}
# Objects in Edit Mode: the last Gaussians read, handed out again while the edit mesh reads the
# same (else every redraw would be new Gaussians, and the viewport would render them again and
# again, a core busy for as long as Edit Mode lasts).
_edit_cache: dict[tuple, tuple[tuple, Gaussians]] = {}


@dataclass
class SplatBatch:
    """One instance's splats, in world space."""

    name: str                 # the original object's name
    gaussians: Gaussians      # world space, SH limited to `sh_degree`
    matrix_world: np.ndarray  # (4, 4) float64, what `gaussians` were transformed by
    antialiased: bool
    sh_degree: int
    color_space: str
    is_instance: bool
    cached: bool


@dataclass
class GatherResult:
    batches: list[SplatBatch]
    gaussians: Gaussians      # every batch, concatenated (SH padded with zeros to the largest)
    seconds: float
    warnings: list[str] = field(default_factory=list)

    @property
    def antialiased(self) -> bool:
        """True when every batch asks for the antialiased mode (see `warnings` if they differ)."""
        return bool(self.batches) and all(b.antialiased for b in self.batches)

    @property
    def cache_hits(self) -> int:
        return sum(b.cached for b in self.batches)


def _bump(uid: int) -> None:
    _generations[uid] = _generations.get(uid, 0) + 1


@persistent
def _on_depsgraph_update(scene, depsgraph) -> None:
    for update in depsgraph.updates:
        if update.is_updated_geometry:
            original = update.id.original
            if original is not None:
                _bump(original.session_uid)


@persistent
def _on_load(*_args) -> None:
    clear_cache()


def clear_cache() -> None:
    _world_cache.clear()
    _combined_cache.clear()
    _edit_cache.clear()


def _same_gaussians(a: Gaussians, b: Gaussians) -> bool:
    return all(x.shape == y.shape and np.array_equal(x, y) for x, y in zip(
        (a.means, a.log_scales, a.quats, a.opacity_logits, a.sh),
        (b.means, b.log_scales, b.quats, b.opacity_logits, b.sh)))
    _generations.clear()


def _generation(id_data) -> int:
    return 0 if id_data is None else _generations.get(id_data.session_uid, 0)


def _read_names(data, degree: int, blender: bool) -> tuple[str, ...]:
    """The attributes the Gaussians of `data` are read from (the add-on's or Blender's)."""
    if blender:
        return blender_data.read_names(data)
    return (splat_object.POSITION, splat_object.ROTATION, splat_object.LOG_SCALE,
            splat_object.OPACITY_LOGIT, splat_object.HIDE) + splat_object.SH_NAMES[:(degree + 1) ** 2]


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


def _contents(data, names: tuple[str, ...]) -> tuple:
    """A checksum of what `splat_object.gaussians_from_data` (or, for Blender's splats,
    `blender_splats.data.read_conversion`) reads from `data` (the `names` attributes: the splat
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


def _settings_for(evaluated, owner):
    for candidate in (evaluated.original, owner):
        if splat_object.is_splat_object(candidate) or blender_data.is_blender_splat_object(candidate):
            return candidate.splat
    return None


def _blender_renders(evaluated, owner) -> bool:
    """A Blender splat point cloud handed back to Blender's own renderer (per object)."""
    for candidate in (evaluated.original, owner):
        if blender_data.is_blender_splat_object(candidate):
            return bool(candidate.splat.render_by_blender)
    return False


def gather(depsgraph, *, objects=None, use_cache: bool = True,
           all_sh_bands: bool = False, space: np.ndarray | None = None,
           include_blender_rendered: bool = False) -> GatherResult:
    """World-space splats of every visible splat geometry in `depsgraph` (or of `objects` and
    the instances they make). See the module docstring for what is read and what is cached.
    `all_sh_bands` keeps every SH band the data holds, ignoring the objects' `sh_degree`.
    `space` (4x4, export's axis conversion) is applied after each world matrix, in the same
    one transform; the product is snapped (`core.axes.snap`) so an import's axis conversion
    undone comes back as the exact identity and the data unchanged, bit for bit.

    Blender 5.3's own splat point clouds (type 'GAUSSIAN_SPLAT', `blender_splats.data`) are
    gathered as the add-on's objects are, except those handed back to Blender's renderer
    (`Object.splat.render_by_blender`) unless `include_blender_rendered` (export)."""
    start = time.perf_counter()
    wanted = None if objects is None else {o.original.session_uid for o in objects}
    batches: list[SplatBatch] = []
    seen: set[tuple] = set()
    local_this_call: dict[tuple, Gaussians] = {}  # one read per geometry, however often instanced
    warnings: list[str] = []

    for instance in depsgraph.object_instances:
        evaluated = instance.object
        if evaluated.type not in ("MESH", "POINTCLOUD"):
            continue
        owner = (instance.parent.original if instance.is_instance and instance.parent is not None
                 else evaluated.original)
        if wanted is not None and owner.session_uid not in wanted \
                and evaluated.original.session_uid not in wanted:
            continue
        data = evaluated.data
        blender = evaluated.type == "POINTCLOUD" and blender_data.is_blender_splat_data(data)
        if blender and ownership.reads_original(evaluated.original):
            data = evaluated.original.data  # a render evaluates it empty (ownership module)
        if blender:
            if not include_blender_rendered and _blender_renders(evaluated, owner):
                continue
            source_degree, notes = attributes.degree_of(
                frozenset(blender_data.attribute_names(data)))
            degree = min(source_degree, attributes.RENDER_MAX_DEGREE)
            warnings.extend(f"{owner.name}: {note}" for note in notes if note not in warnings)
        else:
            degree = splat_object.data_sh_degree(data)
        if degree is None:
            continue
        names = _read_names(data, degree, blender)
        settings = _settings_for(evaluated, owner)
        sh_degree = degree if settings is None or all_sh_bands else min(settings.sh_degree, degree)
        antialiased = False if settings is None else settings.antialiased
        color_space = "SRGB" if settings is None else settings.color_space
        matrix = np.array(instance.matrix_world, dtype=np.float64)
        if space is not None:
            matrix = snap(space @ matrix)
        identity = (evaluated.original.session_uid, owner.session_uid,
                    tuple(instance.persistent_id) if instance.is_instance else None,
                    evaluated.type)
        edit_mode = evaluated.type == "MESH" and data.is_editmode
        fingerprint = None
        if not edit_mode:
            fingerprint = (_generation(evaluated.original), _generation(evaluated.original.data),
                           _generation(owner), data.as_pointer(), splat_object.point_count(data),
                           _attribute_addresses(data, names))
        world_key = (matrix.tobytes(), sh_degree)

        cached = None
        contents = None
        entry = None
        if use_cache and fingerprint is not None:
            entry = _world_cache.get(identity)
            if entry is not None and entry[0] == (fingerprint, world_key):
                cached = entry[1]
            elif entry is not None and entry[0][1] == world_key:
                contents = _contents(data, names)
                if contents == entry[2]:  # a new depsgraph or an edit undone: same Gaussians
                    cached = entry[1]
                    _world_cache[identity] = ((fingerprint, world_key), cached, contents)
        if cached is not None:
            world = cached
        else:
            local_key = (fingerprint, sh_degree) if fingerprint is not None else None
            local = local_this_call.get(local_key) if local_key is not None else None
            if local is None:
                if edit_mode:
                    local = edit_mode_gaussians(evaluated)
                elif blender:
                    conversion = blender_data.read_conversion(data)
                    local = conversion.gaussians
                    warnings.extend(w for w in conversion.warnings if w not in warnings
                                    and "degree" not in w)
                else:
                    local = splat_object.gaussians_from_data(data)
                if sh_degree < local.degree:
                    local = local.with_degree(sh_degree)
                if local_key is not None:
                    local_this_call[local_key] = local
            world = transform_gaussians(local, matrix)
            if use_cache and edit_mode:
                previous = _edit_cache.get(identity)
                if previous is not None and previous[0] == world_key \
                        and _same_gaussians(previous[1], world):
                    world = previous[1]
                    cached = world
                _edit_cache[identity] = (world_key, world)
            if use_cache and fingerprint is not None:
                if contents is None:  # only moved (same data): its contents are known
                    contents = entry[2] if entry is not None and entry[0][0] == fingerprint \
                        else _contents(data, names)
                _world_cache[identity] = ((fingerprint, world_key), world, contents)
        seen.add(identity)
        batches.append(SplatBatch(owner.name, world, matrix, antialiased, sh_degree, color_space,
                                  instance.is_instance, cached is not None))

    if use_cache and objects is None:
        for identity in [k for k in _world_cache if k not in seen]:
            del _world_cache[identity]
        for identity in [k for k in _edit_cache if k not in seen]:
            del _edit_cache[identity]
    if len({b.antialiased for b in batches}) > 1:
        warnings.append("splat objects disagree on the antialiased option: rendering "
                        "without it")
    combined = _combine(batches, use_cache, scope="all" if objects is None else "objects")
    return GatherResult(batches, combined, time.perf_counter() - start, warnings)


def _combine(batches: list[SplatBatch], use_cache: bool, scope: str) -> Gaussians:
    if not batches:
        return Gaussians.empty()
    if len(batches) == 1:
        return batches[0].gaussians
    key = tuple(id(b.gaussians) for b in batches)
    if use_cache and all(b.cached for b in batches):
        entry = _combined_cache.get(scope)
        if entry is not None and entry[0] == key:
            return entry[1]
    degree = max(b.gaussians.degree for b in batches)
    parts = [b.gaussians if b.gaussians.degree == degree else b.gaussians.with_degree(degree)
             for b in batches]
    combined = Gaussians(*(np.concatenate([getattr(p, name) for p in parts])
                           for name in ("means", "log_scales", "quats", "opacity_logits", "sh")))
    if use_cache:
        _combined_cache[scope] = (key, combined)
    return combined


def register() -> None:
    handlers = bpy.app.handlers
    if _on_depsgraph_update not in handlers.depsgraph_update_post:
        handlers.depsgraph_update_post.append(_on_depsgraph_update)
    if _on_load not in handlers.load_post:
        handlers.load_post.append(_on_load)


def unregister() -> None:
    handlers = bpy.app.handlers
    if _on_depsgraph_update in handlers.depsgraph_update_post:
        handlers.depsgraph_update_post.remove(_on_depsgraph_update)
    if _on_load in handlers.load_post:
        handlers.load_post.remove(_on_load)
    clear_cache()
