"""Gaussians shown in place of an object's own while a job updates them (training's snapshots).

A snapshot written into the object's data is a depsgraph update, and Blender answers one with
a redraw of the 3D view per viewport anti-aliasing sample (Workbench's: nine in Blender 4.3,
0.2-0.3 s each in software OpenGL, docs/benchmarks/training_sizes.md). Shown here instead, it
is a change of this source only: the viewport renders it and redraws once. Every path that
gathers (the viewport, F12, export) sees the snapshot, as it would the written data. The job
writes its result into the object when it ends (`end` then drops the snapshot); a file that
loads drops them all (`clear`).
"""

from __future__ import annotations

import itertools

from ...core.gaussians import Gaussians
from .base import Source, settings_of

# original object's session_uid -> (a number new with each snapshot, the job's step, Gaussians)
_snapshots: dict[int, tuple[int, int, Gaussians]] = {}
_numbers = itertools.count(1)


def show(obj, gaussians: Gaussians, step: int) -> None:
    """Show `gaussians` (object space), the job's state at `step`, as `obj`'s splats until
    `end(obj)`."""
    _snapshots[obj.session_uid] = (next(_numbers), step, gaussians)


def end(obj) -> None:
    """`obj` shows its own data again."""
    if obj is not None:
        _snapshots.pop(obj.session_uid, None)


def shown(obj) -> tuple[int, Gaussians] | None:
    """(step, Gaussians) of the snapshot `obj` shows, None when it shows its own data."""
    entry = None if obj is None else _snapshots.get(obj.session_uid)
    return None if entry is None else entry[1:]


class LiveSnapshot(Source):
    kind = "snapshot of a running job"

    @classmethod
    def of(cls, instance, evaluated, owner, is_one, or_one):
        """The snapshot shown for the evaluated object's original, None when there is none.
        `is_one`/`or_one`: the tests of a splat object (its settings, `settings_of`)."""
        entry = _snapshots.get(evaluated.original.session_uid)
        if entry is None:
            return None
        source = cls(instance, evaluated, owner, evaluated.data, entry[2].degree, (),
                     settings_of(evaluated, owner, is_one, or_one))
        source.number, _, source.gaussians = entry
        return source

    def change_key(self) -> tuple:
        return ("snapshot", self.number)

    def contents(self) -> tuple:
        return ("snapshot", self.number)

    def point_count(self) -> int:
        return len(self.gaussians)

    def read(self, warnings: list[str]) -> Gaussians:
        return self.gaussians


def clear() -> None:
    """Every object shows its own data again (a file loads: `gather`'s load handler)."""
    _snapshots.clear()
