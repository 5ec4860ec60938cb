"""Which photos are matched (core/sfm/pairs.py) and the workspace's photo copies
(core/sfm/photos.py): upright, bounded, and their EXIF focal length prior."""

from __future__ import annotations

import math

import numpy as np
import pytest

from addon.core.images import files
from addon.core.sfm import pairs
from addon.core.sfm.photos import bounded_size, exif_focal_px, output_name, write_photo


def test_exhaustive_and_sequential_pairs():
    assert pairs.exhaustive(4) == [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    plain = pairs.sequential(10, overlap=2, quadratic=False)
    assert plain == sorted({(i, j) for i in range(10) for j in (i + 1, i + 2) if j < 10})
    assert pairs.sequential(10, overlap=2) == plain  # quadratic overlap only when asked
    quadratic = set(pairs.sequential(40, overlap=3, quadratic=True))
    assert {(0, 1), (0, 2), (0, 3), (0, 4)} <= quadratic and (0, 5) not in quadratic
    assert len(pairs.sequential(200)) < 200 * 20  # linear in the count


def test_choose_follows_the_capture():
    assert pairs.choose("auto", "video", 500) == "sequential"
    assert pairs.choose("auto", "photos", pairs.EXHAUSTIVE_MAX) == "exhaustive"
    assert pairs.choose("auto", "photos", pairs.EXHAUSTIVE_MAX + 1) == "retrieval"
    assert pairs.choose("exhaustive", "video", 500) == "exhaustive"


def test_retrieval_pairs_photos_of_the_same_place(rng):
    """Three places, each photo's descriptors drawn around its place's own visual words: the
    retrieved pairs stay within a place (beyond the short sequential overlap)."""
    places = [rng.normal(0, 60, size=(40, 128)) + 128 for _ in range(3)]
    descriptors, place_of = [], []
    for photo in range(30):
        place = photo % 3
        words = places[place][rng.integers(0, 40, size=400)]
        descriptors.append(np.clip(words + rng.normal(0, 5, size=words.shape), 0, 255))
        place_of.append(place)
    similar = pairs.similarity(descriptors, words=64)
    chosen = pairs.retrieval(similar, neighbours=5, overlap=0)
    assert len(chosen) < len(pairs.exhaustive(30)) / 2
    assert all(place_of[i] == place_of[j] for i, j in chosen)


def test_bounded_sizes_and_names():
    assert bounded_size(4032, 3024, 1600) == (1600, 1200)
    assert bounded_size(3024, 4032, 1600) == (1200, 1600)
    assert bounded_size(800, 600, 1600) == (800, 600)
    assert bounded_size(4032, 3024, 0) == (4032, 3024)
    taken = {"a.png"}
    from pathlib import Path
    assert output_name(Path("x/a.tif"), taken) == "a_tif.png"
    assert output_name(Path("x/b.JPG"), taken) == "b.JPG"


def test_exif_focal_length_from_the_35mm_equivalent():
    # A 26 mm equivalent (a phone's main camera) on a 4032x3024 photo: 26 / 43.27 of the
    # diagonal, 3,029 pixels.
    assert exif_focal_px(26.0, 4032, 3024) == pytest.approx(26.0 * 5040.0 / math.hypot(36, 24))
    assert exif_focal_px(0.0, 4032, 3024) is None
    assert exif_focal_px(float("nan"), 4032, 3024) is None


def test_a_photo_stored_sideways_is_written_upright_and_bounded(tmp_path, rng):
    import OpenImageIO as oiio

    pixels = rng.integers(0, 256, size=(40, 100, 3), dtype=np.uint8)
    source = tmp_path / "sideways.png"
    spec = oiio.ImageSpec(100, 40, 3, "uint8")
    spec.attribute("Orientation", 6)  # stored turned: shown rotated 90 degrees clockwise
    spec.attribute("Exif:FocalLengthIn35mmFilm", 28)
    out = oiio.ImageOutput.create(str(source))
    assert out.open(str(source), spec) and out.write_image(pixels)
    out.close()
    (tmp_path / "images").mkdir()
    photo = write_photo(source, tmp_path / "images", "sideways.png", max_size=50)
    assert (photo.width, photo.height) == (20, 50)
    written = files.read_pixels(tmp_path / "images" / "sideways.png")
    expected = files.read_pixels(source, orientation=6, size=(20, 50))
    assert written.shape == (50, 20, 3) and np.array_equal(written, expected)
    assert photo.focal_px == pytest.approx(28 * math.hypot(20, 50) / math.hypot(36, 24))
