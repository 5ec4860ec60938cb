"""Splat sequences (4D captures): one splat file per frame, read lazily with a small cache.

A sequence is named by
- a folder: every splat file in it (any format of `registry`) whose name carries a frame number;
- one of its files, e.g. `walk_0007.ply`: every file beside it with the same text around the
  last run of digits (`walk_0001.ply`, `walk_0002.ply`, ...);
- a pattern with `#` for the digits (`walk_####.ply`, any width) or a printf `%04d`.
Frames are ordered by their number; numbers need not start at 0 or be contiguous (a gap holds
the previous frame, as image sequences do in Blender: `file_for(frame)`).

`SplatSequence.gaussians(frame)` reads a frame when it is first asked for and keeps the last
`cache_frames` read, and no more than `cache_bytes` of them (least recently used out; the frame
just read always stays, whatever its size), so memory stays bounded whatever the length or the
frames' sizes, and scrubbing back and forth over cached frames never reads a file again.
Thread-safe.
Counts may change from frame to frame. Blender-free: the Blender side drives it per frame.

Every frame file is judged by `contained.contained_file`, as paths inside splat files are: a frame
that is a link leading outside the sequence's folder, or not a regular file (a FIFO, a device, a
folder), is refused with an error naming it, never followed (sequences often live on shared
storage, where anyone may have put a link).
"""

from __future__ import annotations

import bisect
import os
import re
import threading
from collections import OrderedDict
from pathlib import Path
from typing import Iterable

from ..gaussians import Gaussians
from . import registry
from ..formats_common.contained import contained_file
from ..formats_common.errors import SplatFileError
from ..formats_common.limits import SEQUENCE_CACHE_BYTES

__all__ = ["SplatSequence", "find_frames", "save_sequence"]

_DIGITS = re.compile(r"(\d+)(?!.*\d)")  # the last run of digits in a name
_HASHES = re.compile(r"#+")
_PRINTF = re.compile(r"%0?(\d*)d")


def _is_splat(path: Path) -> bool:
    return any(fmt.matches(path.name) and not fmt.whole_name for fmt in registry.FORMATS)


def _split(name: str) -> tuple[str, int, str] | None:
    """(text before, number, text after) around the last run of digits of a file's stem."""
    match = _DIGITS.search(name)
    if match is None:
        return None
    return name[:match.start()], int(match.group(1)), name[match.end():]


def find_frames(target: str | os.PathLike) -> dict[int, Path]:
    """{frame number: file} of the sequence `target` names (see the module docstring)."""
    target = Path(target)
    if target.is_dir():
        frames: dict[int, Path] = {}
        try:
            paths = sorted(target.iterdir())
        except OSError as e:
            raise SplatFileError(target, f"cannot list the folder: {e.strerror or e}") from None
        for path in paths:
            parts = _split(path.name) if _is_splat(path) else None
            if parts is not None:
                if parts[1] in frames:
                    raise SplatFileError(target, f"two files for frame {parts[1]}: "
                                                 f"{frames[parts[1]].name} and {path.name}")
                frames[parts[1]] = contained_file(target, path.name, target, f"frame {parts[1]}")
        if not frames:
            raise SplatFileError(target, "no numbered splat files in this folder")
        return dict(sorted(frames.items()))
    name = _HASHES.sub(lambda m: "%0" + str(len(m.group())) + "d", target.name, count=1)
    printf = _PRINTF.search(name)
    if printf is not None:
        before, after = name[:printf.start()], name[printf.end():]
    else:
        parts = _split(target.name)
        if parts is None:
            raise SplatFileError(target, "not a sequence: the name has no frame number, # or %d")
        before, _, after = parts
    pattern = re.compile(re.escape(before) + r"(\d+)" + re.escape(after) + "$")
    frames = {}
    folder = target.parent
    try:
        names = sorted(p.name for p in folder.iterdir())
    except OSError as e:
        raise SplatFileError(target, f"cannot list the folder: {e.strerror or e}") from None
    for file_name in names:
        match = pattern.match(file_name)
        if match:
            number = int(match.group(1))
            if number in frames:
                raise SplatFileError(target, f"two files for frame {number}: {frames[number].name} "
                                             f"and {file_name}")
            frames[number] = contained_file(folder, file_name, target, f"frame {number}")
    if not frames:
        raise SplatFileError(target, "no files match this sequence")
    return dict(sorted(frames.items()))


class SplatSequence:
    """The frames of a sequence, read on demand, at most `cache_frames` and `cache_bytes` kept in
    memory (beyond the last one read)."""

    def __init__(self, target: str | os.PathLike, cache_frames: int = 3,
                 cache_bytes: int = SEQUENCE_CACHE_BYTES) -> None:
        if cache_frames < 1:
            raise ValueError(f"cache_frames must be at least 1, got {cache_frames}")
        if cache_bytes < 0:
            raise ValueError(f"cache_bytes must not be negative, got {cache_bytes}")
        self.target = Path(target)
        self.files = find_frames(target)
        self.numbers = list(self.files)
        self.cache_frames, self.cache_bytes = cache_frames, cache_bytes
        self.reads = 0  # files read so far (a cache miss each)
        self._cache: OrderedDict[int, Gaussians] = OrderedDict()
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self.numbers)

    @property
    def first(self) -> int:
        return self.numbers[0]

    @property
    def last(self) -> int:
        return self.numbers[-1]

    def number_for(self, frame: int) -> int:
        """The frame number whose file shows at `frame`: the latest at or before it (the first
        before the sequence starts)."""
        at = bisect.bisect_right(self.numbers, frame)
        return self.numbers[max(at - 1, 0)]

    def file_for(self, frame: int) -> Path:
        return self.files[self.number_for(frame)]

    def gaussians(self, frame: int) -> Gaussians:
        """The Gaussians shown at `frame` (shared with the cache: treat as read-only)."""
        number = self.number_for(frame)
        with self._lock:
            cached = self._cache.get(number)
            if cached is not None:
                self._cache.move_to_end(number)
                return cached
        gaussians = registry.read(self.files[number])[0]  # outside the lock: reads can overlap
        with self._lock:
            self.reads += 1
            self._cache[number] = gaussians
            self._cache.move_to_end(number)
            while len(self._cache) > 1 and (len(self._cache) > self.cache_frames
                                            or self._cached_bytes() > self.cache_bytes):
                self._cache.popitem(last=False)
        return gaussians

    def _cached_bytes(self) -> int:
        return sum(a.nbytes for g in self._cache.values() for a in g.arrays().values())

    def cached_numbers(self) -> list[int]:
        with self._lock:
            return list(self._cache)


def save_sequence(frames: Iterable[tuple[int, Gaussians]], pattern: str | os.PathLike, *,
                  antialiased: bool = False) -> list[Path]:
    """Write (frame number, Gaussians) pairs to `pattern` (`#` or `%04d` for the number, e.g.
    `out/walk_####.ply`); each file atomically, in the format its name gives. Returns the files."""
    pattern = Path(pattern)
    name = _HASHES.sub(lambda m: "%0" + str(len(m.group())) + "d", pattern.name, count=1)
    if _PRINTF.search(name) is None:
        raise SplatFileError(pattern, "a sequence pattern needs # or %d where the frame number goes")
    written = []
    for number, gaussians in frames:
        path = pattern.parent / (name % number)
        registry.write(gaussians, path, antialiased=antialiased)
        written.append(path)
    return written
