"""Video frames for structure from motion (core/sfm/video.py, sharpness.py): the sharpest frame of
each time slice, upright and bounded, and clear errors for videos that cannot become a scene."""

from __future__ import annotations


import numpy as np
import pytest

from addon.core.images import files
from addon.core.sfm import ReconstructionError
from addon.core.sfm.sharpness import laplacian_variance
from addon.core.sfm.video import choose_frames, sample_video, upright
from videos import write_video

pytest.importorskip("av")


def blur(image: np.ndarray, passes: int) -> np.ndarray:
    out = image.astype(np.float32)
    for _ in range(passes):
        out = (np.roll(out, 1, 0) + np.roll(out, -1, 0) + np.roll(out, 1, 1)
               + np.roll(out, -1, 1) + out) / 5.0
    return out


def panning_frames(rng: np.random.Generator, count: int, sharp_every: int,
                   size=(96, 128)) -> list[np.ndarray]:
    """A textured strip seen by a camera panning right; every `sharp_every`-th frame sharp,
    the others blurred (as motion blur does)."""
    height, width = size
    texture = rng.integers(0, 256, size=(height, width + 4 * count, 3)).astype(np.float32)
    frames = []
    for i in range(count):
        view = texture[:, 4 * i:4 * i + width]
        view = view if i % sharp_every == 0 else blur(view, 3)
        frames.append(np.clip(view, 0, 255).astype(np.uint8))
    return frames


def test_laplacian_variance_against_a_direct_sum(rng):
    image = rng.random((7, 9))
    direct = [image[y - 1, x] + image[y + 1, x] + image[y, x - 1] + image[y, x + 1]
              - 4 * image[y, x] for y in range(1, 6) for x in range(1, 8)]
    assert laplacian_variance(image) == pytest.approx(np.var(direct), rel=1e-5)
    assert laplacian_variance(blur(image, 2)) < laplacian_variance(image)
    with pytest.raises(ValueError):
        laplacian_variance(np.zeros((2, 5)))


def test_the_sharpest_of_each_slice_is_chosen():
    sharpness = [1, 5, 2, 9, 0, 0, 3, 1]
    assert choose_frames(sharpness, 4) == [1, 3, 4, 6]
    assert choose_frames(sharpness, 20) == list(range(8))
    assert choose_frames(sharpness, 1) == [3]


def test_upright_follows_the_display_rotation():
    pixels = np.arange(6).reshape(2, 3, 1)
    assert upright(pixels, 0) is pixels
    assert np.array_equal(upright(pixels, 90), np.rot90(pixels, 1))
    assert np.array_equal(upright(pixels, -90), np.rot90(pixels, -1))
    assert upright(pixels, 180).shape == (2, 3, 1)


def drain(steps):
    while True:
        try:
            next(steps)
        except StopIteration as done:
            return done.value


def test_a_video_gives_its_sharp_frames_at_a_bounded_size(tmp_path, rng):
    video = tmp_path / "pan.mp4"
    write_video(video, panning_frames(rng, 40, sharp_every=5), codec="mpeg4")
    out = tmp_path / "images"
    out.mkdir()
    photos = drain(sample_video(video, out, count=8, max_size=64))
    assert [p.name for p in photos] == [f"frame_{i:05d}.jpg" for i in range(0, 40, 5)]
    for photo in photos:
        header = files.read_header(out / photo.name)
        assert (header.width, header.height) == (photo.width, photo.height) == (64, 48)


def test_a_still_video_is_refused(tmp_path, rng):
    video = tmp_path / "still.mp4"
    frame = rng.integers(0, 256, size=(64, 64, 3), dtype=np.uint8)
    write_video(video, [frame] * 20, codec="mpeg4")
    with pytest.raises(ReconstructionError, match="does not move"):
        drain(sample_video(video, tmp_path, count=8, max_size=0))


def test_broken_videos_are_named(tmp_path, rng):
    garbage = tmp_path / "garbage.mp4"
    garbage.write_bytes(rng.integers(0, 256, size=5000, dtype=np.uint8).tobytes())
    with pytest.raises(ReconstructionError, match="garbage.mp4"):
        drain(sample_video(garbage, tmp_path, count=8, max_size=0))
    video = tmp_path / "cut.mp4"
    write_video(video, panning_frames(rng, 30, sharp_every=1), codec="mpeg4")
    data = video.read_bytes()
    video.write_bytes(data[: len(data) // 2])  # truncated: the frames before the cut are used
    out = tmp_path / "images"
    out.mkdir()
    try:
        photos = drain(sample_video(video, out, count=5, max_size=0))
    except ReconstructionError as error:
        assert "cut.mp4" in str(error)
    else:
        assert 3 <= len(photos) <= 5
