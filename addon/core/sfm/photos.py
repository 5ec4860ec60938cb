"""The workspace's photos: each source photo once, upright and at a bounded size.

COLMAP and the trainer read pixels as stored and ignore EXIF orientation, so a photo taken
sideways is written turned upright. Photos larger than `max_size` on their long side are
shrunk (an area average): a 12 MP phone photo gives SIFT nothing a 1600-pixel one lacks, and
training reads 1600 pixels wide by default anyway. A photo already upright and small enough is
copied byte for byte. Every write is atomic, so an interrupted run leaves whole files only.

The camera's focal length prior comes from EXIF `FocalLengthIn35mmFilm` (CIPA DC-002 defines it
through the diagonal angle of view: f_px = f35 * diagonal_px / 43.27 mm). It is only a prior:
photos cropped or exported after capture keep an EXIF focal length that no longer fits their
pixels, so the mapping retries without it (see `mapping`).
"""

from __future__ import annotations

import math
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path

from ..atomic import atomic_write
from ..images import files
from .errors import ReconstructionError


class UnreadablePhoto(ReconstructionError):
    """A source photo that cannot be decoded (corrupt, truncated, not an image): skipped."""

FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)  # 43.27 mm
DEFAULT_MAX_SIZE = 1600


@dataclass(frozen=True)
class Photo:
    """A photo as written into the workspace's `images/`."""

    name: str  # file name in images/
    source: str  # where it came from (a source file name, or a video's frame number)
    width: int
    height: int
    focal_px: float | None  # EXIF focal length prior in pixels (None: not in the file)

    @property
    def camera_key(self) -> tuple:
        """Photos sharing a key share one camera: same size, same lens (or no EXIF)."""
        focal = None if self.focal_px is None else round(self.focal_px, 1)
        return (self.width, self.height, focal)

    def to_json(self) -> dict:
        return asdict(self)


def bounded_size(width: int, height: int, max_size: int) -> tuple[int, int]:
    """(width, height) shrunk so that the long side is at most `max_size` (0: no bound)."""
    longest = max(width, height)
    if max_size <= 0 or longest <= max_size:
        return width, height
    scale = max_size / longest
    return max(1, round(width * scale)), max(1, round(height * scale))


def exif_focal_px(focal_35mm: float, width: int, height: int) -> float | None:
    """Focal length in pixels from EXIF's 35 mm equivalent (None when absent or absurd)."""
    if not (focal_35mm and math.isfinite(focal_35mm)) or not 4.0 <= focal_35mm <= 2000.0:
        return None
    return float(focal_35mm) * math.hypot(width, height) / FULL_FRAME_DIAGONAL_MM


def output_name(source: Path, taken: set[str]) -> str:
    """The name in images/: JPEGs stay JPEG, other formats are written as PNG (lossless)."""
    jpeg = source.suffix.lower() in (".jpg", ".jpeg")
    name = source.name if jpeg or source.suffix.lower() == ".png" else f"{source.stem}.png"
    if name in taken:  # "a.tif" next to "a.png"
        name = f"{source.stem}_{source.suffix.lstrip('.').lower()}{Path(name).suffix}"
    return name


def write_photo(source: Path, images_dir: Path, name: str, max_size: int) -> Photo:
    """Write `source` as `images_dir / name`, upright and bounded. UnreadablePhoto for a photo
    that cannot be decoded; ReconstructionError naming the target when it cannot be written (a
    full disk: that stops the run, it does not skip photos)."""
    try:
        header = files.read_header(source)
        files.check_decodes(source)  # a truncated or corrupt file fails here, by name
        width, height = header.size(oriented=True)
        size = bounded_size(width, height, max_size)
        pixels = None
        if header.orientation != 1 or size != (width, height) or \
                source.suffix.lower() != Path(name).suffix.lower():
            pixels = files.read_pixels(source, orientation=header.orientation, size=size)
    except files.ImageError as error:
        raise UnreadablePhoto(str(error)) from None
    target = images_dir / name
    try:
        if pixels is None:  # upright, small enough, same format: the file as it is
            with open(source, "rb") as src, atomic_write(target) as dst:
                shutil.copyfileobj(src, dst)
        else:
            if pixels.shape[2] in (2, 4):  # alpha: COLMAP and training take colour
                pixels = pixels[:, :, :pixels.shape[2] - 1]
            if target.suffix.lower() == ".jpg" and pixels.dtype != "uint8":
                pixels = (files.to_float(pixels) * 255.0 + 0.5).clip(0, 255).astype("uint8")
            files.write_pixels(target, pixels)
    except OSError as error:  # ImageError included
        raise ReconstructionError(f"{target}: cannot write the photo: "
                                  f"{getattr(error, 'strerror', None) or error}") from None
    return Photo(name, source.name, size[0], size[1], exif_focal_px(header.focal_35mm, *size))
