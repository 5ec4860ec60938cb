"""COLMAP models from strangers (issue 14's reproducers): each gives a clean ColmapError naming
the file and the camera, image or point, in bounded time; no path from a model file leads
outside the folders the user chose, reading or writing; non-finite values are dropped and
counted."""

from __future__ import annotations

import os
import shutil
import struct
import time
from pathlib import Path

import numpy as np
import pytest

from addon.core.colmap import ColmapError, read_colmap


def _workspace(shared_data: Path, tmp_path: Path, change=None, text: bool = False,
               photos: int = 2) -> Path:
    """The beer model (SIMPLE_RADIAL, 71 images), changed by `change(rec)`, in tmp/w/sparse/0,
    with the first `photos` photos (by name) copied into tmp/w/images."""
    import pycolmap

    rec = pycolmap.Reconstruction(str(shared_data / "beer" / "sparse" / "0"))
    names = sorted(im.name for im in rec.images.values())
    if change is not None:
        change(rec)
    work = tmp_path / "w"
    model = work / "sparse" / "0"
    model.mkdir(parents=True)
    (rec.write_text if text else rec.write_binary)(str(model))
    (work / "images").mkdir()
    for name in names[:photos]:
        shutil.copy(shared_data / "beer" / "images" / name, work / "images" / name)
    return work


def _first_image(rec):
    return rec.images[min(rec.images)]


def _timed_error(match: str, *args, **kwargs) -> ColmapError:
    start = time.perf_counter()
    with pytest.raises(ColmapError, match=match) as info:
        read_colmap(*args, **kwargs)
    assert time.perf_counter() - start < 5.0
    return info.value


@pytest.mark.parametrize("size", [(720, 2**64 - 1), (720, 100_000_000), (2**31, 1280), (0, 1280)])
def test_absurd_camera_sizes_are_refused_before_pycolmap(shared_data, tmp_path, size):
    """A distorted camera claiming a height of 2^64 - 1 or 1e8, or a width of 2^31, used to hang
    inside pycolmap's undistortion."""
    def change(rec):
        rec.cameras[1].width, rec.cameras[1].height = size

    work = _workspace(shared_data, tmp_path, change)
    _timed_error(rf"cameras\.bin: camera 1 \(SIMPLE_RADIAL\): size {size[0]}x{size[1]} is outside",
                 work, cache_dir=tmp_path / "cache")


def test_text_cameras_are_checked_too(shared_data, tmp_path):
    work = _workspace(shared_data, tmp_path, text=True)
    cameras = work / "sparse" / "0" / "cameras.txt"
    lines = cameras.read_text().splitlines()
    k = next(i for i, line in enumerate(lines) if line.startswith("1 "))
    words = lines[k].split()
    lines[k] = " ".join(words[:3] + ["100000000"] + words[4:])
    cameras.write_text("\n".join(lines) + "\n")
    _timed_error(r"cameras\.txt: camera 1 \(SIMPLE_RADIAL\): size 720x100000000", work,
                 cache_dir=tmp_path / "cache")
    lines[k] = " ".join(words[:4] + ["nan"] + words[5:])
    cameras.write_text("\n".join(lines) + "\n")
    _timed_error(r"cameras\.txt: camera 1 \(SIMPLE_RADIAL\): non-finite parameters", work,
                 cache_dir=tmp_path / "cache")


def test_non_finite_or_negative_focal_lengths_are_refused(shared_data, tmp_path):
    def change(rec):
        rec.cameras[3].params = [-100.0, 360.0, 640.0, 0.01]

    work = _workspace(shared_data, tmp_path, change)
    _timed_error(r"cameras\.bin: camera 3 \(SIMPLE_RADIAL\): focal lengths must be positive", work,
                 cache_dir=tmp_path / "cache")


def test_image_names_leading_outside_are_refused_reading_and_writing(shared_data, tmp_path):
    """`../../x/evil.jpg` used to be read from outside the image folder and its undistorted copy
    written outside the cache folder."""
    def change(rec):
        _first_image(rec).name = "../../x/evil.jpg"

    work = _workspace(shared_data, tmp_path, change)
    outside = tmp_path / "x"
    outside.mkdir()
    shutil.copy(shared_data / "beer" / "images" / sorted(os.listdir(shared_data / "beer" / "images"))[0],
                outside / "evil.jpg")
    cache = tmp_path / "cache" / "deep"
    error = _timed_error(r"images\.bin: image \d+ '\.\./\.\./x/evil\.jpg': the name leads outside",
                         work, cache_dir=cache)
    assert "refused" in str(error)
    assert sorted(p.name for p in outside.iterdir()) == ["evil.jpg"]
    assert not (tmp_path / "cache").exists() or not any(
        p.is_file() for p in (tmp_path / "cache").rglob("*") if "deep" not in p.parts)


def test_links_in_the_image_folder_or_the_cache_cannot_lead_outside(shared_data, tmp_path):
    work = _workspace(shared_data, tmp_path, photos=1)
    first = sorted(os.listdir(work / "images"))[0]
    # a photo that is a link to a file outside the image folder: not read
    (work / "images" / first).unlink()
    secret = tmp_path / "secret.jpg"
    shutil.copy(shared_data / "beer" / "images" / first, secret)
    (work / "images" / first).symlink_to(secret)
    _timed_error(rf"\({first}: it is a link leading outside .*; refused\)", work,
                 cache_dir=tmp_path / "c")
    scene = read_colmap(work, cache_dir=tmp_path / "c", require_photos=False)
    assert scene.image(first).path is None and "refused" in scene.missing[first]

    # a cache folder (downloaded with the scene) holding a link that leads outside: refused
    (work / "images" / first).unlink()
    shutil.copy(secret, work / "images" / first)
    scene = read_colmap(work, cache_dir=tmp_path / "c")
    copy = scene.image(first).path
    assert copy.is_relative_to(scene.undistorted_dir)
    copy.unlink()
    target = tmp_path / "target.jpg"
    copy.symlink_to(target)
    (scene.undistorted_dir / "manifest.json").unlink()
    _timed_error("undistorted copy: .* leads outside", work, cache_dir=tmp_path / "c")
    assert not target.exists()


def test_non_finite_points_and_observations_are_dropped_and_counted(shared_data, tmp_path):
    def change(rec):
        ids = sorted(rec.points3D)
        rec.points3D[ids[0]].xyz = np.array([np.nan, 0.0, 0.0])
        rec.points3D[ids[1]].error = np.inf
        image = _first_image(rec)
        observed = [k for k, p in enumerate(image.points2D) if p.has_point3D()]
        for k in observed[:3]:
            image.points2D[k].xy = np.array([np.inf, 1.0])

    clean = read_colmap(_workspace(shared_data, tmp_path / "a"), cache_dir=tmp_path / "c1",
                        copy_photos=False)
    scene = read_colmap(_workspace(shared_data, tmp_path / "b", change), cache_dir=tmp_path / "c2",
                        copy_photos=False)
    assert scene.dropped == {"points3D": 2, "observations": 3} and clean.dropped == {}
    assert len(scene.points) == len(clean.points) - 2
    assert np.isfinite(scene.points.xyz).all() and np.isfinite(scene.points.error).all()
    for im in scene.images:
        assert np.isfinite(im.points2D).all()
    # the undistorted model in the cache holds none of them either
    import pycolmap
    cached = pycolmap.Reconstruction(str(scene.undistorted_dir / "sparse" / "0"))
    assert len(cached.points3D) <= len(scene.points)
    assert all(np.isfinite(p.xyz).all() for p in cached.points3D.values())


def test_non_finite_pose_names_the_image(shared_data, tmp_path):
    import pycolmap

    def change(rec):
        image = _first_image(rec)
        pose = image.cam_from_world()
        rec.frames[image.frame_id].rig_from_world = pycolmap.Rigid3d(
            pycolmap.Rotation3d(pose.rotation.quat), np.array([np.inf, 0.0, 0.0]))

    work = _workspace(shared_data, tmp_path, change)
    _timed_error(r"images\.bin: image '.*': non-finite pose", work, cache_dir=tmp_path / "c")


def _patch_binary(path: Path, offset: int, data: bytes) -> None:
    raw = bytearray(path.read_bytes())
    raw[offset:offset + len(data)] = data
    path.write_bytes(bytes(raw))


def test_point_id_beyond_int64_is_a_named_error(shared_data, tmp_path):
    """It used to be an OverflowError from numpy. The point is observed by no image (pycolmap
    checks observed ones against the images), as the last record of points3D.bin."""
    import pycolmap

    def change(rec):
        rec.add_point3D(np.zeros(3), pycolmap.Track(), np.zeros(3, np.uint8))

    work = _workspace(shared_data, tmp_path, change)
    points = work / "sparse" / "0" / "points3D.bin"
    _patch_binary(points, points.stat().st_size - 51, struct.pack("<Q", 2**64 - 2))
    _timed_error(r"points3D\.bin: point3D id 18446744073709551614 is out of range", work,
                 cache_dir=tmp_path / "c", copy_photos=False)


def test_non_utf8_image_name_is_a_named_error(shared_data, tmp_path):
    """It used to be a UnicodeDecodeError."""
    work = _workspace(shared_data, tmp_path)
    images = work / "sparse" / "0" / "images.bin"
    raw = images.read_bytes()
    name_at = 8 + 64  # first image: id, quaternion, translation, camera id; then its name
    assert raw[name_at:name_at + 1].isascii()
    _patch_binary(images, name_at, b"\xff")
    _timed_error(r"images\.bin: image \d+: its name is not UTF-8", work, cache_dir=tmp_path / "c")


@pytest.mark.parametrize("name, offset, what", [("frames.bin", 8 + 64, "data ids cannot fit"),
                                                ("rigs.bin", 8 + 4, "sensors cannot fit")])
def test_lying_counts_in_rigs_and_frames_fail_fast(shared_data, tmp_path, name, offset, what):
    """Found by tests/core/formats/test_fuzz.py: a frame's data-id count of 2^32 - 1 hung pycolmap's reader."""
    work = _workspace(shared_data, tmp_path)
    _patch_binary(work / "sparse" / "0" / name, offset, struct.pack("<I", 2**32 - 1))
    _timed_error(rf"{name}: corrupt COLMAP binary file at byte \d+: 4294967295 {what}", work,
                 cache_dir=tmp_path / "c", copy_photos=False)


@pytest.mark.parametrize("text", [False, True], ids=["bin", "txt"])
def test_an_image_name_no_file_system_holds_is_a_named_error(shared_data, tmp_path, text):
    """A 300-character image name: looking for its photo raised a raw OSError (Errno 36, file
    name too long) from `renamed_photos`."""
    def change(rec):
        _first_image(rec).name = "a" * 300 + ".jpg"

    work = _workspace(shared_data, tmp_path, change, text=text)
    images = "images.txt" if text else "images.bin"
    _timed_error(rf"{images}: image \d+ 'a+': a part of 304 bytes, more than the 255 .*; refused", work,
                 cache_dir=tmp_path / "c")


def test_a_photo_path_the_os_cannot_open_is_a_missing_photo(tmp_path):
    """Every part of the name fits, the whole path does not: that photo is missing, with the
    OS's reason (no OSError out of the search)."""
    from types import SimpleNamespace

    from addon.core.colmap.model import find_photos

    (tmp_path / "images").mkdir()
    name = "/".join(["a" * 250] * 16) + "/x.jpg"
    found, missing = find_photos([SimpleNamespace(name=name, camera_id=1)], None, tmp_path / "images")
    assert not found and name in missing
