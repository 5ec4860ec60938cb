"""The total memory bound every splat reader checks before it allocates anything.

A file's size alone does not bound what it decodes to: `.spz` is compressed (zstd can reach
ratios in the thousands on degenerate data), and a PLY header is free to declare anything its
file size allows. So every reader refuses a file that declares more than `MAX_GAUSSIANS`
Gaussians, from the header, before it decompresses or allocates. Loading N Gaussians peaks at
N x 125-730 bytes, by format and SH degree (measured: docs/guide/formats.md), so the
default ceiling keeps a load under about 7.5 GB. It bounds a whole file, not one part of it:
the glTF reader counts every node's instance of a mesh, the streamed-SOG reader every run of the
level, before either reads a buffer or image. Raise it for bigger scenes: set
`MAX_GAUSSIANS` here, or the environment variable SPLAT_MAX_GAUSSIANS before the add-on loads.

A count under that ceiling can still come from a file of kilobytes: a SOG whose meta.json
declares 10M Gaussians over uniform WebPs of 460 bytes, a gzip `.spz` of zeros, a glTF showing
one primitive through hundreds of nodes. So every compressed or instancing reader also bounds
the *expansion*: the bytes of the Gaussians a file declares (float32, `gaussian_bytes`) per byte
of the file (every file it is made of), `MAX_EXPANSION`, checked from the headers before
anything is decoded (`check_expansion`). Raise it for a genuine file beyond it (a glTF instancing
one primitive many times): set `MAX_EXPANSION` here, or SPLAT_MAX_EXPANSION before the add-on
loads.
"""

from __future__ import annotations

import os
from contextlib import contextmanager
from typing import Iterator

from .errors import SplatFileError

DEFAULT_MAX_GAUSSIANS = 10_000_000  # the biggest published 3DGS scenes hold about 6 million
ENVIRONMENT_VARIABLE = "SPLAT_MAX_GAUSSIANS"
# Measured (docs/benchmarks/expansion.md, 2026-11-28): the worst real file, level 0_0 of the
# streamed SOG playbot_sog, declares 8.9 bytes of Gaussians per byte read; biker.spz 3.8; no file
# of the formats tests beyond EXPANSION_SLACK more; a synthetic untrained SH3 scene (random
# positions, everything else constant: what compresses best and is still genuine) 31 as SOG and
# 25 as .spz. 256 leaves 28 times the real worst and 8 times that one; issue 33's hostile files
# ask 650 (a .glb of 166 instances) to 100,000 (a SOG folder of 5 KB).
DEFAULT_MAX_EXPANSION = 256
EXPANSION_VARIABLE = "SPLAT_MAX_EXPANSION"
# Declared bytes every file may have whatever its size: tiny files (a handful of Gaussians,
# headers and JSON around them) are never refused, and a megabyte bounds nothing dangerous.
EXPANSION_SLACK = 1 << 20


# What a sequence keeps of the frames it read (formats/sequence.py), besides the one shown: three
# frames of a million SH3 Gaussians (708 MB) fit; frames of 10M SH3 (2.4 GB) are kept one at a time.
SEQUENCE_CACHE_BYTES = 2 << 30


def _from_environment(name: str, default: int) -> int:
    text = os.environ.get(name, "")
    try:
        value = int(text)
    except ValueError:
        return default
    return value if value > 0 else default


MAX_GAUSSIANS = _from_environment(ENVIRONMENT_VARIABLE, DEFAULT_MAX_GAUSSIANS)
MAX_EXPANSION = _from_environment(EXPANSION_VARIABLE, DEFAULT_MAX_EXPANSION)


@contextmanager
def expansion_bound(bound: int) -> Iterator[None]:
    """`MAX_EXPANSION` is `bound` inside the block (the importer's "Max Expansion")."""
    global MAX_EXPANSION
    before, MAX_EXPANSION = MAX_EXPANSION, int(bound)
    try:
        yield
    finally:
        MAX_EXPANSION = before


def check_gaussian_count(path: str | os.PathLike, count: int, what: str = "Gaussians") -> None:
    """Refuse a declared count above `MAX_GAUSSIANS`, naming the file and how to raise it."""
    if count > MAX_GAUSSIANS:
        raise SplatFileError(path, f"declares {count} {what}, more than the limit of {MAX_GAUSSIANS} "
                                   f"per file (raise formats_common.limits.MAX_GAUSSIANS or set "
                                   f"{ENVIRONMENT_VARIABLE} if the file is genuine)")


def gaussian_bytes(count: int, degree: int) -> int:
    """Bytes `count` loaded Gaussians of SH degree `degree` (0..3; higher reads as 3) hold:
    float32 means, log scales, quaternions, opacity and (degree + 1)^2 RGB coefficients."""
    return 4 * count * (3 + 3 + 4 + 1 + 3 * (min(degree, 3) + 1) ** 2)


def check_expansion(path: str | os.PathLike, count: int, degree: int, file_bytes: int,
                    what: str = "") -> None:
    """Refuse a file of `file_bytes` bytes declaring `count` Gaussians of SH `degree` whose
    bytes exceed `MAX_EXPANSION` times the file (plus `EXPANSION_SLACK`), naming the file, the
    declared size, the bound and how to raise it. `what` says where the count comes from."""
    declared = gaussian_bytes(count, degree)
    if declared <= MAX_EXPANSION * file_bytes + EXPANSION_SLACK:
        return
    ratio = declared / max(file_bytes, 1)
    raise SplatFileError(path, f"declares {count} Gaussians{what} of SH degree {min(degree, 3)} "
                               f"({declared / 2**20:.1f} MiB loaded) in {file_bytes} bytes: {ratio:.0f} "
                               f"bytes decoded per byte read, more than the bound of {MAX_EXPANSION} "
                               f"(real files ask under 32; far more is a decompression bomb or made "
                               f"to look like one: if the file is genuine, an instanced glTF say, "
                               f"raise Max Expansion in File > Import > Gaussian Splats, "
                               f"formats_common.limits.MAX_EXPANSION in a script, or set "
                               f"{EXPANSION_VARIABLE} before Blender starts)")
