"""What the user gave: a folder of photos or a video file, and which files of it are used.

A folder's photos are its JPEG, PNG and TIFF files (not its subfolders); every other entry is
skipped and named with the reason, as is a link that leads out of the folder. Names are sorted
naturally ("2.jpg" before "10.jpg"): that is the capture order of phone and camera names, which
sequential matching relies on.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from ..colmap.checks import is_inside
from .errors import ReconstructionError

PHOTO_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff")
VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".mkv", ".webm", ".avi")


def natural_key(name: str) -> tuple:
    """Sort key reading runs of digits as numbers: "img2" < "img10"."""
    return tuple((0, int(part), part) if part.isdigit() else (1, 0, part.lower())
                 for part in re.split(r"(\d+)", name) if part)


@dataclass
class Source:
    path: Path  # the folder or the video file, resolved
    kind: str  # "photos" or "video"
    photos: list[Path] = field(default_factory=list)  # the photos used, in natural order
    skipped: list[tuple[str, str]] = field(default_factory=list)  # (name, why)


def is_video(path: Path) -> bool:
    return path.suffix.lower() in VIDEO_SUFFIXES


def find_source(path: str | Path) -> Source:
    """The photos of a folder, or a video file; ReconstructionError if there is neither."""
    path = Path(path).expanduser()
    if path.is_file():
        if not is_video(path):
            raise ReconstructionError(
                f"{path}: not a video ({', '.join(VIDEO_SUFFIXES)}) nor a folder of photos")
        return Source(path.resolve(), "video")
    if not path.is_dir():
        raise ReconstructionError(f"{path}: no such folder or video file")
    root = path.resolve()
    source = Source(root, "photos")
    for entry in sorted(root.iterdir(), key=lambda p: natural_key(p.name)):
        if entry.name.startswith("."):
            continue
        if not is_inside(root, entry):
            source.skipped.append((entry.name, f"a link that leads outside {root}"))
        elif entry.is_dir():
            source.skipped.append((entry.name, "a folder (only the photos in the folder "
                                               "itself are used)"))
        elif entry.suffix.lower() not in PHOTO_SUFFIXES:
            source.skipped.append((entry.name, "not a JPEG, PNG or TIFF photo"))
        else:
            source.photos.append(entry)
    if not source.photos:
        raise ReconstructionError(f"{root}: no JPEG, PNG or TIFF photos in this folder")
    return source
