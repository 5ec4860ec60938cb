"""Gather the splats a depsgraph shows, in world space, ready for `addon.core.render.renderer.render`.

`gather(depsgraph)` walks `depsgraph.object_instances` (so it sees exactly what Blender would
render: visibility, modifiers, geometry nodes, instancing, parenting, constraints, drivers and
animation at the depsgraph's frame are all already applied), finds each instance's source
(`sources.source_of`: the add-on's object, its edit-mode mesh, Blender 5.3's splat point
cloud), asks it for its Gaussians in object space (SH bands limited to the object's
`sh_degree` option) and transforms them by the matrix it renders with
(`addon.core.transform.transform_gaussians`: centres, rotations, scales and SH bands 1-3; a
non-uniform scale re-decomposes each covariance exactly and rotates the SH by the polar
rotation; a source that does both for less, a deformed splat object or cloud turning each SH
once, gives them in world space itself: `Source.read_world`), then batches and caches them.
Render options come from the splat object the geometry belongs to: the evaluated object itself
when it is a splat object, else the instancer (`obj.splat`), else the defaults.

`objects=[...]` limits the gather to those objects and to the instances they make (export).

Cache: each instance's world-space Gaussians are kept, keyed by
  - the source's identity: original object, instancer, `persistent_id`, geometry type;
  - its change key (a geometry fingerprint, `sources.base`): update counters of the original
    object, its data and the instancer, bumped by this module's `depsgraph_update_post` handler
    for every ID the depsgraph reports with `is_updated_geometry`, plus the addresses of the
    evaluated attribute arrays and the point count;
  - the world matrix (exact bytes) and the SH degree used.
A moved object re-transforms; a changed geometry is read again; anything unchanged costs a
dictionary lookup. When that fingerprint misses (every final render evaluates a new depsgraph,
so its addresses are new, and a script may edit data in place with no handler running), a
checksum of the attribute contents (`splatcore.checksum` of every attribute the Gaussians are
read from, read in place: about 2.5 ms for 125k SH-2 splats, where a CRC-32 of `foreach_get`
copies took 6 to 7) decides: the same contents, the same world matrix
and SH degree reuse the transformed Gaussians (F12 again, the frames of an animation), anything
else reads and transforms again. The concatenation of all batches is cached the same way (a single
batch is returned as is). Sources without a change key (objects in Edit Mode: their evaluated
data is a BMesh wrapper) are never cached by it. `clear_cache()` empties everything; loading a
file does it too. Returned arrays are shared with the cache: treat them as read-only.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import bpy
import numpy as np
from bpy.app.handlers import persistent

from ...core.gaussians import Gaussians
from ...core.transform import transform_gaussians
from . import base, deformed, live, source_of
from .base import Source

_world_cache: dict[tuple, tuple[tuple, Gaussians, tuple]] = {}  # key, world, contents
_combined_cache: dict[str, tuple[tuple, Gaussians]] = {}
# Sources without a change key (Edit Mode): the last Gaussians read, handed out again while
# the edit mesh reads the same (else every redraw would be new Gaussians, and the viewport would
# render them again and again, a core busy for as long as Edit Mode lasts).
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
    shown: bool = True        # the object's "Show in Viewport" (`Object.splat.show_in_viewport`)


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


@persistent
def _on_depsgraph_update(scene, depsgraph) -> None:
    for update in depsgraph.updates:
        if update.is_updated_geometry:
            original = update.id.original
            if original is not None:
                base.bump(original.session_uid)


@persistent
def _on_load(*_args) -> None:
    clear_cache()
    live.clear()


def clear_cache() -> None:
    deformed.clear()
    _world_cache.clear()
    _combined_cache.clear()
    _edit_cache.clear()


def _same_gaussians(a: Gaussians, b: Gaussians) -> bool:
    return all(x.shape == y.shape and np.array_equal(x, y) for x, y in zip(
        (a.means, a.log_scales, a.quats, a.opacity_logits, a.sh),
        (b.means, b.log_scales, b.quats, b.opacity_logits, b.sh)))


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
        source = source_of(instance, wanted=wanted,
                           include_blender_rendered=include_blender_rendered)
        if source is None:
            continue
        owner = source.owner
        warnings.extend(f"{owner.name}: {note}" for note in source.notes if note not in warnings)
        sh_degree = source.sh_degree(all_sh_bands)
        matrix = source.matrix(space)
        world, cached = _world(source, matrix, sh_degree, use_cache, local_this_call, warnings)
        seen.add(source.identity)
        batches.append(SplatBatch(owner.name, world, matrix, source.antialiased, sh_degree,
                                  source.color_space, instance.is_instance, cached, source.shown))

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


def _world(source: Source, matrix: np.ndarray, sh_degree: int, use_cache: bool,
           local_this_call: dict, warnings: list[str]) -> tuple[Gaussians, bool]:
    """The source's Gaussians in world space (`matrix`, `sh_degree`) and whether they came
    from the cache: kept while its change key and the world key hold, or while its contents
    read the same; read once per call however often it is instanced."""
    identity = source.identity
    fingerprint = source.change_key()
    world_key = (matrix.tobytes(), sh_degree)
    cached = contents = entry = None
    if use_cache and fingerprint is not None:
        entry = _world_cache.get(identity)
        if entry is not None and entry[0] == (fingerprint, world_key):
            cached = entry[1]
        elif entry is not None and entry[0][1] == world_key:
            contents = source.contents()
            if contents == entry[2]:  # a new depsgraph or an edit undone: same Gaussians
                cached = entry[1]
                _world_cache[identity] = ((fingerprint, world_key), cached, contents)
    if cached is not None:
        return cached, True
    local_key = (fingerprint, sh_degree) if fingerprint is not None else None
    local = local_this_call.get(local_key) if local_key is not None else None
    world = source.read_world(matrix, sh_degree, warnings) if local is None else None
    if world is None:
        if local is None:
            local = source.read(warnings)
            if sh_degree < local.degree:
                local = local.with_degree(sh_degree)
            if local_key is not None:
                local_this_call[local_key] = local
        world = transform_gaussians(local, matrix)
    if use_cache and not source.keyed:
        previous = _edit_cache.get(identity)
        if previous is not None and previous[0] == world_key \
                and _same_gaussians(previous[1], world):
            world = cached = previous[1]
        _edit_cache[identity] = (world_key, world)
    if use_cache and fingerprint is not None:
        if contents is None:  # only moved (same data): its contents are known
            contents = entry[2] if entry is not None and entry[0][0] == fingerprint \
                else source.contents()
        _world_cache[identity] = ((fingerprint, world_key), world, contents)
    return world, cached is not None


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
