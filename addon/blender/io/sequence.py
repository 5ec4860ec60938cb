"""Splat sequences in Blender: a splat object whose Gaussians are those of the frame's file.

An object with `obj.splat.sequence_source` set (a numbered file, a `####` pattern or a folder;
see `core.formats.sequence`) shows, at scene frame F, the file numbered
F + `sequence_frame_offset` (a gap or a frame outside holds the nearest earlier file). A
`frame_change_pre` handler rewrites the object's mesh before Blender evaluates the frame, so the
viewport, `gather`, F12 and `blender -a` see an ordinary splat object and need no changes.

Memory stays bounded: each object has one `SplatSequence` (module-level, keyed by the object's
session id), whose cache keeps the last few frames read; scrubbing over them reads no file. The
frame number the mesh shows is stored on the mesh (`SHOWN_KEY`), so undo and saved files stay
consistent with it and an unchanged frame rewrites nothing. Objects in Edit Mode are left
alone. A frame that cannot be read keeps the previous splats and prints the error (once per
frame): a handler has no operator to report through; during a final render it fails the render
instead, so no frame is written with another frame's splats.
"""

from __future__ import annotations

import re
import sys
import threading
from pathlib import Path

import bpy
from bpy.app.handlers import persistent

from ...core.formats_common.errors import SplatFileError
from ...core.formats.sequence import SplatSequence
from ...core.gaussians import Gaussians
from ..render import failures, state
from .. import splat_object
from ..registration import module_registration

CACHE_FRAMES = 3  # frames each sequence keeps in memory
SHOWN_KEY = "splat_sequence_frame"  # on the mesh: the file number its splats come from
NUMBERS_KEY = "splat_sequence_numbers"  # on the object: the file numbers seen at import ("1-6,9")

# object session uid -> (absolute source, SplatSequence)
_sequences: dict[int, tuple[str, SplatSequence]] = {}
_reported: set[tuple[str, int]] = set()  # (source, number) whose read failure was printed
_lock = threading.Lock()  # F12 animation calls the handler from the render thread


def source_of(obj) -> str:
    """The absolute sequence source of `obj`, or "" when it is not a sequence."""
    settings = getattr(obj, "splat", None)
    if settings is None or not settings.is_splat or not settings.sequence_source:
        return ""
    return bpy.path.abspath(settings.sequence_source)


def sequence_of(obj) -> SplatSequence | None:
    """The object's `SplatSequence` (made when first asked for, or when its source changed);
    None when it is not a sequence. SplatFileError when the source names no frames."""
    source = source_of(obj)
    if not source:
        return None
    uid = obj.session_uid
    with _lock:
        entry = _sequences.get(uid)
        if entry is not None and entry[0] == source:
            return entry[1]
    sequence = SplatSequence(source, cache_frames=CACHE_FRAMES)
    with _lock:
        _sequences[uid] = (source, sequence)
    return sequence


def adopt(obj, sequence: SplatSequence) -> None:
    """Use `sequence` (already holding the frames an import read) for `obj`."""
    with _lock:
        _sequences[obj.session_uid] = (source_of(obj), sequence)


def file_number(obj, sequence: SplatSequence, frame: int) -> int:
    """The number of the file `obj` shows at scene frame `frame`."""
    return sequence.number_for(frame + obj.splat.sequence_frame_offset)


def mark_shown(obj, number: int) -> None:
    obj.data[SHOWN_KEY] = int(number)


def record_numbers(obj, numbers) -> None:
    """Remember which file numbers the sequence had when it was imported (as ranges), so that a
    machine that lacks one of them (a render farm worker whose copy is incomplete) fails that
    frame instead of showing the previous file as a gap."""
    numbers = sorted(set(int(n) for n in numbers))
    ranges, start = [], None
    for i, n in enumerate(numbers):
        start = n if start is None else start
        if i + 1 == len(numbers) or numbers[i + 1] != n + 1:
            ranges.append(str(start) if start == n else f"{start}-{n}")
            start = None
    obj[NUMBERS_KEY] = ",".join(ranges)


def recorded_numbers(obj) -> set[int]:
    """The file numbers `record_numbers` kept (empty for objects imported before it existed)."""
    found: set[int] = set()
    for part in str(obj.get(NUMBERS_KEY, "")).split(","):
        first, _, last = part.partition("-")
        if first.strip().lstrip("-").isdigit():
            found.update(range(int(first), int(last or first) + 1))
    return found


def _check_delivered(obj, sequence: SplatSequence, frame: int) -> None:
    """During a final render: the file this frame should show was there at import; if it is not
    here now, the render must not show the previous file in its place."""
    wanted = frame + obj.splat.sequence_frame_offset
    if wanted in sequence.files or wanted not in recorded_numbers(obj):
        return
    neighbour = sequence.files[sequence.number_for(wanted)]
    name = re.sub(r"(\d+)(?!.*\d)", lambda m: str(wanted).zfill(len(m.group(1))), neighbour.name)
    raise SplatFileError(neighbour.parent / name,
                         f"frame {wanted}'s file is missing (the sequence had it at import; "
                         f"this machine has {len(sequence)} of its files)")


def show_frame(obj, frame: int) -> bool:
    """Make `obj`'s mesh hold the Gaussians of scene frame `frame`. True when it was rewritten.
    Raises SplatFileError (the source or the frame's file cannot be read)."""
    sequence = sequence_of(obj)
    if sequence is None or obj.data is None or obj.data.is_editmode:
        return False
    if state.current.scene is not None:
        _check_delivered(obj, sequence, frame)
    number = file_number(obj, sequence, frame)
    if obj.data.get(SHOWN_KEY) == number:
        return False
    gaussians: Gaussians = sequence.gaussians(number)
    splat_object.replace_gaussians(obj, gaussians)
    mark_shown(obj, number)
    return True


def update_scene(scene, frame: int | None = None) -> None:
    """Show the frame (default the scene's current) on every sequence object of `scene`;
    errors are printed once per file and leave the object as it was, except during a final
    render, which they fail (see `failures`)."""
    frame = scene.frame_current if frame is None else frame
    for obj in scene.objects:
        if obj.type != "MESH" or not source_of(obj):
            continue
        try:
            show_frame(obj, frame)
        except (SplatFileError, OSError, ValueError) as error:
            if state.current.scene == scene.name:  # a final render must not show stale splats
                failures.fail_render(
                    scene, f"{obj.name!r} cannot show frame {frame} of its sequence: {error}",
                    "frame")
                continue
            key = (source_of(obj), frame)
            if key not in _reported:
                _reported.add(key)
                print(f"Gaussian splats: {obj.name!r} keeps its splats at frame {frame}: {error}",
                      file=sys.stderr)


@persistent
def _on_frame_change_pre(scene, _depsgraph=None) -> None:
    try:
        update_scene(scene)
    except Exception as error:  # never let a handler break a frame change or a render
        print(f"Gaussian splats: sequence update failed at frame {scene.frame_current}: "
              f"{error!r}", file=sys.stderr)


@persistent
def _on_load_post(*_args) -> None:
    """A new file: object session ids start over, so the sequences do too."""
    forget_all()


def forget_all() -> None:
    with _lock:
        _sequences.clear()
    _reported.clear()


def loaded_sequences() -> int:
    """How many sequences are held (each with at most `CACHE_FRAMES` frames in memory)."""
    with _lock:
        return len(_sequences)


_register_handlers, _unregister_handlers = module_registration(
    handlers=[("frame_change_pre", _on_frame_change_pre), ("load_post", _on_load_post)])


def register() -> None:
    _register_handlers()


def unregister() -> None:
    _unregister_handlers()
    forget_all()


def sequence_pattern(path: str | Path) -> str:
    """An export pattern from a file name: kept when it has `#` or `%d`, else `_####` is added
    before the extension (`walk.ply` -> `walk_####.ply`)."""
    path = Path(path)
    if "#" in path.name or "%" in path.name:
        return str(path)
    return str(path.with_name(f"{path.stem}_####{path.suffix}"))
