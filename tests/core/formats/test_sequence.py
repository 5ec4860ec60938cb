"""Splat sequences (`formats/sequence.py`): finding the frames, lazy reads with a bounded cache,
frames of different counts, writing a sequence back."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from addon.core import splat_io
from addon.core.cameras import Camera
from addon.core.formats_common.errors import SplatFileError
from addon.core.formats.sequence import SplatSequence, find_frames, save_sequence
from addon.core.gaussians import Gaussians
from addon.core.render.renderer import render


def frame(n: int, shift: float) -> Gaussians:
    rng = np.random.default_rng(n)
    means = rng.normal(0, 0.3, (n, 3)) + [shift, 0, 0]
    return Gaussians(means, np.full((n, 3), -3.0), np.tile([1.0, 0, 0, 0], (n, 1)), np.full(n, 2.0),
                     rng.uniform(-1, 1, (n, 4, 3)))


@pytest.fixture()
def walk(tmp_path: Path) -> Path:
    for number, count in ((1, 100), (2, 150), (3, 80)):
        splat_io.save(frame(count, 0.3 * number), tmp_path / f"walk_{number:04d}.ply")
    (tmp_path / "notes.txt").write_text("not a frame")
    (tmp_path / "other_0001.spz").write_bytes(b"")  # another sequence beside it
    return tmp_path


def test_frames_from_a_file_a_pattern_and_a_folder(walk: Path) -> None:
    expected = [walk / f"walk_{n:04d}.ply" for n in (1, 2, 3)]
    for target in (walk / "walk_0002.ply", walk / "walk_####.ply", walk / "walk_%04d.ply"):
        assert list(find_frames(target).values()) == expected
    (walk / "other_0001.spz").unlink()
    assert list(find_frames(walk).values()) == expected


def test_three_frames_render_three_images_with_bounded_reads(walk: Path) -> None:
    sequence = SplatSequence(walk / "walk_0001.ply", cache_frames=2)
    assert (len(sequence), sequence.first, sequence.last) == (3, 1, 3)
    camera = Camera.look_at((0.6, 0, -3), (0.6, 0, 0), (0, -1, 0), width=48, height=32)
    images = [render(sequence.gaussians(f), camera).rgb for f in (1, 2, 3)]
    assert not np.allclose(images[0], images[1]) and not np.allclose(images[1], images[2])
    assert sequence.reads == 3 and sequence.cached_numbers() == [2, 3]  # frame 1 left the cache
    for _ in range(5):  # scrubbing over cached frames reads nothing
        sequence.gaussians(3)
        sequence.gaussians(2)
    assert sequence.reads == 3
    assert len(sequence.gaussians(1)) == 100 and sequence.reads == 4
    assert sequence.cached_numbers() == [2, 1]  # memory: never more than cache_frames frames


def test_frames_outside_and_between_hold_the_nearest_earlier(walk: Path) -> None:
    (walk / "walk_0002.ply").rename(walk / "walk_0005.ply")
    sequence = SplatSequence(walk / "walk_####.ply")
    assert [sequence.number_for(f) for f in (-3, 1, 2, 4, 5, 99)] == [1, 1, 1, 3, 5, 5]
    assert len(sequence.gaussians(4)) == 80


def test_save_sequence_round_trip(tmp_path: Path) -> None:
    frames = [(10, frame(20, 0.0)), (11, frame(30, 1.0))]
    (tmp_path / "out").mkdir()
    written = save_sequence(frames, tmp_path / "out" / "f_###.spz")
    assert [p.name for p in written] == ["f_010.spz", "f_011.spz"]
    sequence = SplatSequence(tmp_path / "out")
    assert [len(sequence.gaussians(f)) for f in (10, 11)] == [20, 30]


def test_errors_name_the_target(tmp_path: Path) -> None:
    for target, message in ((tmp_path, "no numbered splat files"), (tmp_path / "x_####.ply", "no files match"),
                            (tmp_path / "plain.ply", "no frame number")):
        with pytest.raises(SplatFileError, match=message) as error:
            find_frames(target)
        assert str(target) in str(error.value)
    splat_io.save(frame(5, 0), tmp_path / "a_1.ply")
    splat_io.save(frame(5, 0), tmp_path / "a_001.ply")
    with pytest.raises(SplatFileError, match="two files for frame 1"):
        find_frames(tmp_path / "a_#.ply")
    with pytest.raises(SplatFileError, match="needs # or %d"):
        save_sequence([], tmp_path / "plain.ply")
    with pytest.raises(ValueError, match="cache_frames"):
        SplatSequence(tmp_path / "a_1.ply", cache_frames=0)


def test_the_cache_is_bounded_in_bytes_not_only_in_frames(walk: Path) -> None:
    """Issue 33: the cache held 3 frames whatever their size (3 GB for three frames asking 1 GB
    each). Now frames leave it once they pass `cache_bytes` too; the last one read stays."""
    size = sum(a.nbytes for a in SplatSequence(walk / "walk_0001.ply").gaussians(1).arrays().values())
    sequence = SplatSequence(walk / "walk_0001.ply", cache_frames=3, cache_bytes=int(2.5 * size))
    for f in (1, 2, 3):
        sequence.gaussians(f)
    cached = sequence.cached_numbers()
    assert cached[-1] == 3 and sequence._cached_bytes() <= 2.5 * size and len(cached) < 3
    tiny = SplatSequence(walk / "walk_0001.ply", cache_bytes=0)
    for _ in range(3):
        tiny.gaussians(2)
    assert tiny.cached_numbers() == [2] and tiny.reads == 1  # the frame shown stays
    with pytest.raises(ValueError, match="cache_bytes"):
        SplatSequence(walk / "walk_0001.ply", cache_bytes=-1)
