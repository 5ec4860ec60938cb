"""The total memory bound every splat reader checks before it allocates anything.

A file's size alone does not bound what it decodes to: `.spz` is compressed (zstd can reach
ratios in the thousands on degenerate data), and a PLY header is free to declare anything its
file size allows. So every reader refuses a file that declares more than `MAX_GAUSSIANS`
Gaussians, from the header, before it decompresses or allocates. Loading N Gaussians peaks at
N x 125-730 bytes, by format and SH degree (measured: docs/guide/formats.md), so the
default ceiling keeps a load under about 7.5 GB. Raise it for bigger scenes: set
`MAX_GAUSSIANS` here, or the environment variable SPLAT_MAX_GAUSSIANS before the add-on loads.
"""

from __future__ import annotations

import os

from .errors import SplatFileError

DEFAULT_MAX_GAUSSIANS = 10_000_000  # the biggest published 3DGS scenes hold about 6 million
ENVIRONMENT_VARIABLE = "SPLAT_MAX_GAUSSIANS"


def _from_environment() -> int:
    text = os.environ.get(ENVIRONMENT_VARIABLE, "")
    try:
        value = int(text)
    except ValueError:
        return DEFAULT_MAX_GAUSSIANS
    return value if value > 0 else DEFAULT_MAX_GAUSSIANS


MAX_GAUSSIANS = _from_environment()


def check_gaussian_count(path: str | os.PathLike, count: int, what: str = "Gaussians") -> None:
    """Refuse a declared count above `MAX_GAUSSIANS`, naming the file and how to raise it."""
    if count > MAX_GAUSSIANS:
        raise SplatFileError(path, f"declares {count} {what}, more than the limit of {MAX_GAUSSIANS} "
                                   f"per file (raise formats.limits.MAX_GAUSSIANS or set "
                                   f"{ENVIRONMENT_VARIABLE} if the file is genuine)")
