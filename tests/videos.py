"""Videos for the reconstruction's tests and benchmarks, written with PyAV (which the extension
bundles to read them)."""

from __future__ import annotations

from pathlib import Path
from typing import Iterable

import numpy as np


def write_video(path: Path, frames: Iterable[np.ndarray], *, rate: int = 10,
                codec: str = "libx264") -> None:
    """Frames (H, W, 3) uint8, all one size, as a video file. H.264 at CRF 18, a phone's
    quality (an encoder's default bit rate blurs the frames); `mpeg4` at its best quantiser
    for frames whose sides H.264 would round."""
    import av

    options = {"crf": "18"} if codec == "libx264" else {"qscale": "2"}
    with av.open(str(path), "w") as container:
        stream = None
        for frame in frames:
            if stream is None:
                stream = container.add_stream(codec, rate=rate, options=options)
                stream.height, stream.width = frame.shape[:2]
                stream.pix_fmt = "yuv420p"
            for packet in stream.encode(av.VideoFrame.from_ndarray(frame, format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)


def photos_as_video(photos: list[Path], path: Path, rate: int = 10) -> None:
    """Photos (in the given order) as the frames of an H.264 video."""
    from addon.core.images import files

    write_video(path, (files.read_pixels(p)[:, :, :3] for p in photos), rate=rate)
