"""SOG folders and .sog bundles from strangers (issue 29): the Gaussian limit, zip bombs bounded
in total, member names that leave the folder or cannot be files, corrupt members, bad images
named after the user's file (never a temporary one), links and FIFOs beside meta.json, deep
JSON. Each must be a SplatFileError naming the file, in bounded time and memory."""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

from addon.core import splat_io
from addon.core.formats import sog
from addon.core.formats_common import limits
from addon.core.formats_common.errors import SplatFileError
from limited import load_limited
from scripts import fuzz_hostile
from scenes import random_gaussians

pytest.importorskip("OpenImageIO")


@pytest.fixture
def folder(tmp_path: Path, rng: np.random.Generator) -> Path:
    """`user/meta.json` and its images (50 Gaussians, SH degree 1); `outside/` beside it."""
    (tmp_path / "outside").mkdir()
    sog.save(random_gaussians(rng, 50, 1), tmp_path / "user" / "meta.json")
    return tmp_path / "user" / "meta.json"


def members(path: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(path.parent.iterdir())}


def bundle(path: Path, files: dict[str, bytes], compression=zipfile.ZIP_STORED) -> Path:
    with zipfile.ZipFile(path, "w") as archive:
        for name, data in files.items():
            info = zipfile.ZipInfo(name)
            info.compress_type = compression
            archive.writestr(info, data)
    return path


def edited(meta: bytes, change) -> bytes:
    document = json.loads(meta)
    change(document)
    return json.dumps(document).encode()


def test_the_gaussian_limit_applies_before_any_image_is_read(folder: Path, monkeypatch) -> None:
    """A 13 KB folder declaring 12M Gaussians loaded them (2.3 GB); now refused from meta.json."""
    meta = folder.read_bytes()
    folder.write_bytes(edited(meta, lambda m: m.update(count=12_000_000)))
    with pytest.raises(SplatFileError, match="declares 12000000 Gaussians, more than the limit"):
        sog.load(folder)
    folder.write_bytes(meta)
    monkeypatch.setattr(limits, "MAX_GAUSSIANS", 49)
    with pytest.raises(SplatFileError, match="declares 50 Gaussians, more than the limit of 49"):
        sog.load(folder)
    with pytest.raises(SplatFileError, match="limit of 49"):
        sog.read_info(folder)


def test_a_zip_bomb_is_bounded_in_total(folder: Path) -> None:
    """Members of 64 MB of zeros each (64 KB deflated): unpacking stops at what the bundle can
    justify (16x its size + 4 MB), before anything is written; it wrote gigabytes of scratch
    files."""
    files = members(folder)
    for name in files:
        if name.endswith(".webp"):
            files[name] = bytes(64 << 20)
    path = bundle(folder.parent / "bomb.sog", files, zipfile.ZIP_DEFLATED)
    assert path.stat().st_size < 1 << 20
    scratch = set(Path(tempfile.gettempdir()).glob("sog-*"))
    start = time.process_time()
    with pytest.raises(SplatFileError, match="more than the .* this bundle can justify") as error:
        sog.load(path)
    assert time.process_time() - start < 1.0 and str(error.value).startswith(str(path))
    assert set(Path(tempfile.gettempdir()).glob("sog-*")) == scratch  # cleaned up


@pytest.mark.parametrize("member", [".", "..", "x" * 5000, "C:/means_l.webp", "../means_l.webp",
                                    "\\\\host\\share\\means_l.webp", "a/../../means_l.webp", "CON"])
def test_member_names_are_judged_and_never_become_file_names(folder: Path, member: str) -> None:
    """'.' raised IsADirectoryError, a long name OSError (file name too long), `C:/` passed."""
    files = members(folder)
    files["meta.json"] = edited(files["meta.json"], lambda m: m["means"].update(files=[member, "means_u.webp"]))
    files[member] = files.pop("means_l.webp")
    path = bundle(folder.parent / "names.sog", files)
    with pytest.raises(SplatFileError) as error:
        sog.load(path)
    assert str(error.value).startswith(str(path))


def test_a_long_member_name_is_read_under_a_scratch_name(folder: Path) -> None:
    """300 characters: a fine member name, too long for a file name (it raised OSError)."""
    files = members(folder)
    long = "x" * 300 + ".webp"
    files["meta.json"] = edited(files["meta.json"], lambda m: m["means"].update(files=[long, "means_u.webp"]))
    files[long] = files.pop("means_l.webp")
    assert len(sog.load(bundle(folder.parent / "long.sog", files))) == 50


def test_a_corrupt_deflated_member_is_a_named_error(folder: Path) -> None:
    """A damaged deflate stream raised zlib.error."""
    files = members(folder)
    path = bundle(folder.parent / "corrupt.sog", files, zipfile.ZIP_DEFLATED)
    data = bytearray(path.read_bytes())
    with zipfile.ZipFile(path) as archive:
        info = archive.getinfo("meta.json")
    start = info.header_offset + 30 + len(info.filename)
    data[start:start + 8] = b"\xff" * 8  # the compressed bytes, not the CRC in the header
    path.write_bytes(bytes(data))
    with pytest.raises(SplatFileError, match="cannot unpack meta.json") as error:
        sog.load(path)
    assert str(error.value).startswith(str(path))


def test_a_bad_image_is_named_after_the_bundle_and_the_member(folder: Path) -> None:
    files = members(folder)
    files["quats.webp"] = b"RIFF\x10\x00\x00\x00WEBPVP8L" + bytes(8)
    path = bundle(folder.parent / "image.sog", files)
    with pytest.raises(SplatFileError, match="quats.webp") as error:
        sog.load(path)
    assert str(error.value).startswith(str(path))
    assert tempfile.gettempdir() + os.sep + "sog-" not in str(error.value)


@pytest.mark.skipif(sys.platform == "win32", reason="FIFOs and /dev/zero")
@pytest.mark.parametrize("target", ["link_out", "fifo", "dev_zero", "folder"])
def test_images_beside_meta_json_must_be_regular_files_inside_the_folder(folder: Path, target: str) -> None:
    user = folder.parent
    outside = user.parent / "outside"
    (outside / "quats.webp").write_bytes((user / "quats.webp").read_bytes())
    (user / "quats.webp").unlink()
    if target == "link_out":
        os.symlink(outside / "quats.webp", user / "quats.webp")
    elif target == "fifo":
        os.mkfifo(user / "quats.webp")
    elif target == "dev_zero":
        os.symlink("/dev/zero", user / "quats.webp")
    else:
        (user / "quats.webp").mkdir()
    kind, text = load_limited(folder, seconds=30)
    assert kind == "SplatFileError" and text.startswith(str(folder)), (kind, text)
    assert "quats.webp" in text and ("leads outside" in text or "not a regular file" in text)


def test_deeply_nested_meta_json_is_a_named_error(folder: Path) -> None:
    text = folder.read_text()
    folder.write_text(text[:-1] + ', "deep": ' + "[" * 50_000 + "]" * 50_000 + "}")
    with pytest.raises(SplatFileError, match="meta.json nests 50001 levels deep"):
        sog.load(folder)
    path = bundle(folder.parent / "deep.sog", {**members(folder)})
    with pytest.raises(SplatFileError, match="nests 50001 levels deep"):
        splat_io.load(path)


@pytest.mark.parametrize("name, reason", [("x" * 300 + ".webp", "a part of 305 bytes"),
                                          ("a\0b.webp", "NUL character")])
def test_an_image_name_no_file_system_holds_is_a_named_error(folder: Path, name: str, reason: str) -> None:
    """A folder SOG's image name is a file name: one the OS refuses (it raised OSError Errno 36)
    is a SplatFileError naming meta.json, the image and why."""
    folder.write_bytes(edited(folder.read_bytes(), lambda m: m["quats"].update(files=[name])))
    with pytest.raises(SplatFileError, match=f"(image|quats).*{reason}") as error:
        sog.load(folder)
    assert str(error.value).startswith(str(folder))


def test_a_nul_in_a_bundle_member_name_is_a_named_error(folder: Path) -> None:
    files = members(folder)
    files["meta.json"] = edited(files["meta.json"], lambda m: m["quats"].update(files=["q\0.webp"]))
    path = bundle(folder.parent / "nul.sog", files)
    with pytest.raises(SplatFileError, match="bad file name 'q.x00.webp' in quats.files of meta.json: a NUL"):
        sog.load(path)


@pytest.mark.parametrize("form", ["folder", "bundle"])
def test_a_few_kb_declaring_10m_gaussians_is_refused_by_its_expansion(tmp_path: Path, form: str) -> None:
    """Issue 33: meta.json declaring ~10M Gaussians over uniform 3162x3162 lossless WebPs of 460
    bytes each (a few KB in all) loaded 10M Gaussians, 1.97 GB at peak. Refused from meta.json
    and the images' file sizes, before any image is decoded, naming the file and the bound."""
    files = fuzz_hostile.sog_bomb(bundle=form == "bundle")
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    path = tmp_path / ("a.sog" if form == "bundle" else "meta.json")
    assert sum(len(d) for d in files.values()) < 17_000
    start = time.process_time()
    with pytest.raises(SplatFileError, match=rf"declares {fuzz_hostile.COUNT} Gaussians of SH degree 0 "
                                             rf"\(534\.0 MiB loaded\) in \d+ bytes: \d+ bytes decoded per byte "
                                             rf"read, more than the bound of 256") as error:
        sog.load(path)
    assert str(error.value).startswith(str(path)) and time.process_time() - start < 1.0
    monkeypatch = pytest.MonkeyPatch()
    with monkeypatch.context() as m:  # the bound, not another check, refused it
        m.setattr(limits, "MAX_EXPANSION", 10**6)
        m.setattr(sog, "_image", lambda *a, **k: (_ for _ in ()).throw(SplatFileError(path, "decoding")))
        with pytest.raises(SplatFileError, match="decoding"):
            sog.load(path)
