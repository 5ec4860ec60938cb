"""Frames of a video for structure from motion: a target count, the sharpest of each time slice.

Two passes over the video (PyAV, which carries its own FFmpeg): the first decodes every frame at
a quarter size, in grey, and keeps only its sharpness (`sharpness.laplacian_variance`), so the
frame count need not be known in advance and memory stays at one frame; the frames are then cut
into `count` equal slices in order and the sharpest of each slice is chosen (motion blur is what
ruins a phone capture first); the second pass writes the chosen frames, upright (the stream's
display rotation applied) and at most `max_size` pixels on the long side, as JPEG. A video whose
frames hardly differ (the camera did not move) is refused: it holds no parallax to reconstruct.
"""

from __future__ import annotations

from pathlib import Path
from typing import Generator

import numpy as np

from ..images import files
from .errors import ReconstructionError
from .photos import Photo, bounded_size
from .sharpness import laplacian_variance

DEFAULT_FRAME_COUNT = 200
STILL_DIFFERENCE = 0.02  # mean |difference| of quarter-size grey frames in [0, 1]: no motion
MIN_FRAMES = 3


def _open(path: Path):
    try:
        import av
    except ImportError as error:
        raise ReconstructionError(
            f"{path}: reading videos needs the Python module 'av' (PyAV), which this Python "
            f"cannot load ({error})") from error
    try:
        container = av.open(str(path))
    except (av.error.FFmpegError, OSError, ValueError) as error:
        raise ReconstructionError(f"{path}: cannot read the video: {error}") from None
    if not container.streams.video:
        container.close()
        raise ReconstructionError(f"{path}: the file holds no video stream")
    stream = container.streams.video[0]
    stream.thread_type = "AUTO"
    return av, container, stream


def _frames(path: Path):
    """Every decodable frame of the video's first stream, in order. A truncated or corrupt file
    ends the frames where decoding fails (what came before is kept)."""
    av, container, stream = _open(path)
    try:
        for packet in container.demux(stream):
            try:
                yield from packet.decode()
            except av.error.FFmpegError:
                continue  # one bad packet: skip it, as players do
    except av.error.FFmpegError:
        return  # the container itself is damaged from here on
    finally:
        container.close()


def upright(pixels: np.ndarray, rotation: float) -> np.ndarray:
    """Pixels turned by the stream's display rotation (degrees counter-clockwise, as FFmpeg's
    display matrix gives it; phones store portrait video as landscape plus a rotation)."""
    turns = int(round(float(rotation or 0) / 90.0)) % 4
    return np.ascontiguousarray(np.rot90(pixels, k=turns)) if turns else pixels


def choose_frames(sharpness: list[float], count: int) -> list[int]:
    """The sharpest frame of each of `count` equal slices of the frames, in order."""
    n = len(sharpness)
    if count >= n:
        return list(range(n))
    bounds = np.linspace(0, n, count + 1).round().astype(int)
    return [int(a + np.argmax(sharpness[a:b])) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]


def sample_video(path: Path, images_dir: Path, count: int, max_size: int
                 ) -> Generator[tuple[int, int], None, list[Photo]]:
    """Write the chosen frames into `images_dir`; yields (frames done, frames in this pass) and
    returns their `Photo`s. ReconstructionError for a file with too few frames or no motion."""
    sharpness: list[float] = []
    first = None
    moved = 0.0
    for frame in _frames(path):
        small = frame.reformat(width=max(frame.width // 4, 3), height=max(frame.height // 4, 3),
                               format="gray").to_ndarray().astype(np.float32) / 255.0
        sharpness.append(laplacian_variance(small))
        if first is None:
            first = small
        elif small.shape == first.shape:
            moved = max(moved, float(np.abs(small - first).mean()))
        if len(sharpness) % 25 == 0:
            yield len(sharpness), 0
    if len(sharpness) < MIN_FRAMES:
        raise ReconstructionError(f"{path}: only {len(sharpness)} frame(s) could be decoded; "
                                  f"the file is empty, truncated or not a video")
    if moved < STILL_DIFFERENCE:
        raise ReconstructionError(f"{path}: the camera does not move in this video (its frames "
                                  f"differ by {100 * moved:.1f} % at most): a scene needs views "
                                  f"from different places; walk around the subject")
    chosen = choose_frames(sharpness, max(int(count), MIN_FRAMES))
    wanted = set(chosen)
    photos: list[Photo] = []
    for index, frame in enumerate(_frames(path)):
        if index not in wanted:
            continue
        rotation = getattr(frame, "rotation", 0)
        turned = int(round(float(rotation or 0) / 90.0)) % 2 == 1
        width, height = (frame.height, frame.width) if turned else (frame.width, frame.height)
        width, height = bounded_size(width, height, max_size)
        scaled = frame.reformat(width=height if turned else width,
                                height=width if turned else height, format="rgb24",
                                interpolation="AREA")
        pixels = upright(scaled.to_ndarray(), rotation)
        name = f"frame_{index:05d}.jpg"
        files.write_pixels(images_dir / name, pixels)
        photos.append(Photo(name, f"frame {index}", width, height, None))
        yield len(photos), len(chosen)
        if len(photos) == len(chosen):
            break
    if len(photos) < MIN_FRAMES:
        raise ReconstructionError(f"{path}: the video could not be decoded a second time")
    return photos
