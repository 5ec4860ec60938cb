"""The one judge of paths written inside a splat file (glTF buffer `uri`s, SOG member names, LOD
chunk names, sequence frames): a file from a stranger must never make us read outside the folder
the user chose, nor block on or exhaust something that is not a file.

A name is judged by the rules of every platform the extension ships for, whatever platform reads
it (a file made on Linux is opened on Windows): refused when absolute in POSIX or Windows form
(`/etc`, `C:/`, `C:\\`, `\\Windows`, `\\\\host\\share`, `//host/share`), drive-relative (`C:x`), when
`..` (split on both `/` and `\\`) climbs above the folder, when a part holds `:` (a drive, a URL
scheme, an NTFS stream) or NUL, or names a Windows device (`CON`, `NUL`, `COM1.txt`, ...). A name
no file system can hold is refused too where it names a file (`contained_file`, COLMAP image
names), with its own reason (`unrepresentable`): NUL, lone surrogates, a part longer than
`MAX_PART_BYTES`, a whole name longer than `MAX_NAME_CHARS`; the OS would otherwise answer with a
raw OSError ("File name too long") or ValueError ("embedded null byte"). A name that passes must
then, links followed, still lie inside the folder and be a regular file (not a FIFO, device,
socket or folder).
"""

from __future__ import annotations

import os
import stat
from pathlib import Path, PurePosixPath, PureWindowsPath

from .errors import SplatFileError

__all__ = ["is_contained_name", "unrepresentable", "contained_file", "read_regular", "MAX_NAME_CHARS",
           "MAX_PART_BYTES"]

MAX_NAME_CHARS = 4096  # longer than any path a platform opens
MAX_PART_BYTES = 255  # one file or folder name: Linux's and macOS's NAME_MAX (bytes), Windows' 255 UTF-16 units
_WINDOWS_DEVICES = {"CON", "PRN", "AUX", "NUL", "CONIN$", "CONOUT$"} | \
    {f"{d}{i}" for d in ("COM", "LPT") for i in list("123456789") + ["¹", "²", "³"]}


def unrepresentable(name: str) -> str | None:
    """Why no file system can hold `name` (a relative path, `/` or `\\` between its parts), or
    None when one can. The reason is a phrase for an error message."""
    if not isinstance(name, str):
        return "not a text name"
    if len(name) > MAX_NAME_CHARS:
        return f"a name of {len(name)} characters, more than the {MAX_NAME_CHARS} any platform opens"
    if "\0" in name:
        return "a NUL character in the name, which no file system holds"
    try:
        parts = [part.encode("utf-8") for part in PureWindowsPath(name).parts]
    except UnicodeEncodeError:
        return "characters that are not Unicode (lone surrogates), which no file system holds"
    longest = max((len(part) for part in parts), default=0)
    if longest > MAX_PART_BYTES:
        return (f"a part of {longest} bytes, more than the {MAX_PART_BYTES} a file system holds "
                f"in one file or folder name")
    return None


def is_contained_name(name: str) -> bool:
    """Does the relative path `name` stay inside the folder it names into, on every platform?
    (Whether a file system can hold it is `unrepresentable`'s question: a member of a `.sog`
    bundle is never a file name, so a long one is fine there.)"""
    if not isinstance(name, str) or not name or len(name) > MAX_NAME_CHARS or "\0" in name:
        return False
    for pure in (PurePosixPath(name), PureWindowsPath(name)):
        if pure.is_absolute() or pure.drive or pure.root:
            return False
    depth = 0
    for part in PureWindowsPath(name).parts:  # splits on both / and \
        if ":" in part or part.split(".")[0].rstrip(" ").upper() in _WINDOWS_DEVICES:
            return False
        depth += -1 if part == ".." else 0 if part == "." else 1
        if depth < 0:
            return False
    return depth > 0


def contained_file(root: str | os.PathLike, name: str, file: str | os.PathLike, what: str) -> Path:
    """`root / name` when `name` passes `is_contained_name`, the path (links followed) lies inside
    `root` and it is a regular file; else a SplatFileError naming `file` (the user's file) and
    `what` (the item: "buffers[0].uri", "chunk 3", ...)."""
    shown = name if not isinstance(name, str) or len(name) <= 200 else name[:200] + "..."
    problem = unrepresentable(name)
    if problem is None and not is_contained_name(name):
        problem = f"must be a relative path inside the folder {root}"
    if problem is not None:
        raise SplatFileError(file, f"{what} {shown!r}: {problem}; refused")
    path = Path(root) / name.replace("\\", "/")
    try:
        real, real_root = os.path.realpath(path), os.path.realpath(root)
        inside = real.startswith(real_root.rstrip(os.sep) + os.sep)
        mode = os.stat(real).st_mode if inside else 0
    except FileNotFoundError:
        raise SplatFileError(file, f"missing {what} {shown!r} in {root}") from None
    except (OSError, RuntimeError, ValueError) as e:  # loops, name too long, not a folder
        raise SplatFileError(file, f"{what} {shown!r}: cannot open: "
                                   f"{getattr(e, 'strerror', None) or e}") from None
    if not inside:
        raise SplatFileError(file, f"{what} {shown!r}: leads outside the folder {root} "
                                   f"(through a link); refused")
    if not stat.S_ISREG(mode):
        raise SplatFileError(file, f"{what} {shown!r}: not a regular file; refused")
    return path


def read_regular(path: str | os.PathLike, shown: str | os.PathLike, what: str,
                 limit: int | None = None, first: int | None = None) -> bytes:
    """The bytes of the regular file `path` (at most `limit` of them, when given: more is an
    error; only the `first` bytes, when given), or a SplatFileError naming `shown` and `what`.
    Opened without blocking, so a FIFO swapped in after `contained_file` judged the name is
    refused, not waited on."""
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0)
    try:
        fd = os.open(path, flags)
    except OSError as e:
        raise SplatFileError(shown, f"cannot read {what}: {e.strerror or e}") from None
    with os.fdopen(fd, "rb") as f:
        try:
            info = os.fstat(fd)
            if not stat.S_ISREG(info.st_mode):
                raise SplatFileError(shown, f"{what} is not a regular file")
            if limit is not None and info.st_size > limit:
                raise SplatFileError(shown, f"{what} is larger than {limit} bytes")
            if hasattr(os, "set_blocking"):
                os.set_blocking(fd, True)
            data = f.read(first if first is not None else -1 if limit is None else limit + 1)
        except OSError as e:
            raise SplatFileError(shown, f"cannot read {what}: {e.strerror or e}") from None
    if limit is not None and len(data) > limit:
        raise SplatFileError(shown, f"{what} is larger than {limit} bytes")
    return data
