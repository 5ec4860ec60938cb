"""Atomic file writes: write a temporary file beside the target, then rename it over the target
in one step, so a reader never sees half a file and a failed write leaves the old file as it was.

`atomic_path` serves writers that open files by name (OpenImageIO, `numpy.savez`); the temporary
name keeps the target's extension, which such writers read the format from. `atomic_write` is
the same for code that writes bytes itself. `move_files_into` serves writers that fill a folder
(pycolmap): they write into a scratch folder, whose files are then renamed into place.
"""

from __future__ import annotations

import contextlib
import os
import uuid
from pathlib import Path
from typing import BinaryIO, Iterator


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """A temporary path beside `path` to write to; on success it replaces `path`, on failure it
    is removed."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex[:12]}.tmp{path.suffix}")
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def move_files_into(folder: str | os.PathLike, target: str | os.PathLike) -> None:
    """Rename every file of `folder` into `target`, each in one step (a rename replaces a file
    or a link by its name, never what a link points at)."""
    for written in Path(folder).iterdir():
        os.replace(written, Path(target) / written.name)


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike) -> Iterator[BinaryIO]:
    """Open a temporary file for binary writing; on success it replaces `path` in one step."""
    with atomic_path(path) as tmp, open(tmp, "xb") as f:
        yield f
        f.flush()
        os.fsync(f.fileno())
