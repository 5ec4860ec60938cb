"""The one exception type every splat file reader and writer raises; the one refusal of
Gaussians holding NaN or Inf that every writer (and the readers' last net) makes; the one
translation of the OS's errors (a full disk, a missing file) into it."""

from __future__ import annotations

import contextlib
import os
from typing import TYPE_CHECKING, Iterator

if TYPE_CHECKING:
    from ..gaussians import Gaussians


class SplatFileError(ValueError):
    """A splat file could not be read or written; the message names the file and the problem."""

    def __init__(self, path: str | os.PathLike, problem: str) -> None:
        super().__init__(f"{os.fspath(path)}: {problem}")
        self.path = os.fspath(path)
        self.problem = problem


@contextlib.contextmanager
def os_errors(path: str | os.PathLike, doing: str = "cannot write file") -> Iterator[None]:
    """An OSError inside the block becomes a SplatFileError naming `path`: "{doing}: {reason}"."""
    try:
        yield
    except OSError as e:
        raise SplatFileError(path, f"{doing}: {e.strerror or e}") from None


def check_savable(path: str | os.PathLike, gaussians: Gaussians) -> None:
    """A writer's first check: Gaussians holding NaN or Inf are refused (such a file would not
    load again, and some formats cannot even encode them)."""
    bad = gaussians.non_finite()
    if bad is not None:
        raise SplatFileError(path, f"cannot save non-finite values in {bad} (Gaussians.{bad} holds NaN or Inf)")


def check_decoded(path: str | os.PathLike, gaussians: Gaussians) -> Gaussians:
    """A reader's net under its own checks: decoded Gaussians holding NaN or Inf (non-finite
    bounds, say) are refused; else they are returned."""
    bad = gaussians.non_finite()
    if bad is not None:
        raise SplatFileError(path, f"non-finite values in decoded {bad}")
    return gaussians
