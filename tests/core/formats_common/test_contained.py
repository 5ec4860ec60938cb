"""The one judge of paths inside splat files (issue 29): every platform's forms, links, and
files that are not regular."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from addon.core.formats_common.contained import contained_file, is_contained_name, unrepresentable
from addon.core.formats_common.errors import SplatFileError

ESCAPING = ["../x.bin", "a/../../x.bin", "/etc/passwd", "/dev/zero", "C:/Windows/win.ini",
            "C:\\Windows\\win.ini", "C:x.bin", "c:", "..\\..\\x.bin", "a\\..\\..\\x.bin",
            "\\\\host\\share\\x.bin", "//host/share/x.bin", "\\Windows\\x.bin", "\\x.bin",
            "file:///etc/passwd", "http://example.com/x.bin", "x.bin:stream", "CON", "nul.bin",
            "a/COM1.txt", "LPT9", "aux .txt", ".", "./", "a/..", "", "a\0b", "x" * 5000]
INSIDE = ["x.bin", "a/b/x.bin", "a\\b\\x.bin", "./x.bin", "a/../x.bin", "con_tent.bin", "x..bin",
          "...bin", "COM0.txt"]


@pytest.mark.parametrize("name", ESCAPING)
def test_names_leaving_the_folder_on_any_platform_are_refused(name: str) -> None:
    assert not is_contained_name(name)


@pytest.mark.parametrize("name", INSIDE)
def test_names_inside_the_folder_pass(name: str) -> None:
    assert is_contained_name(name)


def test_contained_file_refuses_links_out_fifos_devices_and_folders(tmp_path: Path) -> None:
    user, outside = tmp_path / "user", tmp_path / "outside"
    user.mkdir(), outside.mkdir()
    (outside / "secret.bin").write_bytes(b"secret")
    (user / "ok.bin").write_bytes(b"ok")
    (user / "sub").mkdir()
    os.symlink(outside / "secret.bin", user / "link_out.bin")
    os.symlink("ok.bin", user / "link_in.bin")
    os.symlink(outside, user / "folder_out")
    os.symlink("/dev/zero", user / "zero.bin")
    os.symlink("loop.bin", user / "loop.bin")
    if sys.platform != "win32":
        os.mkfifo(user / "pipe.bin")
    owner = user / "scene.gltf"
    assert contained_file(user, "ok.bin", owner, "buffers[0].uri") == user / "ok.bin"
    assert contained_file(user, "link_in.bin", owner, "buffers[0].uri") == user / "link_in.bin"
    cases = {"link_out.bin": "leads outside", "folder_out/secret.bin": "leads outside",
             "zero.bin": "leads outside", "pipe.bin": "not a regular file", "sub": "not a regular file",
             "missing.bin": "missing buffers", "loop.bin": "cannot open", "../outside/secret.bin":
             "must be a relative path", "C:/x.bin": "must be a relative path"}
    for name, message in cases.items():
        with pytest.raises(SplatFileError, match=message) as error:
            contained_file(user, name, owner, "buffers[0].uri")
        assert str(error.value).startswith(str(owner)) and "buffers[0].uri" in str(error.value)


# Names no file system holds (issue 33): the OS would answer with a raw OSError (Errno 36, "File
# name too long") or ValueError ("embedded null byte"); each is refused with its own reason.
UNREPRESENTABLE = {"a" * 300 + ".bin": "a part of 304 bytes", "sub/" + "é" * 128 + "/x.bin": "a part of 256 bytes",
                   "a\0b.bin": "NUL character", "a\ud800.bin": "not Unicode", "x/" * 2100: "4200 characters"}


@pytest.mark.parametrize("name", UNREPRESENTABLE)
def test_names_no_file_system_holds_are_refused_with_the_reason(tmp_path: Path, name: str) -> None:
    assert UNREPRESENTABLE[name] in unrepresentable(name)
    with pytest.raises(SplatFileError, match=f"buffers.0..uri .*{UNREPRESENTABLE[name]}") as error:
        contained_file(tmp_path, name, tmp_path / "a.gltf", "buffers[0].uri")
    assert str(error.value).startswith(str(tmp_path / "a.gltf"))


def test_the_longest_names_a_file_system_holds_pass() -> None:
    assert unrepresentable("a" * 255) is None and unrepresentable("a/" * 2000) is None
    assert unrepresentable("é" * 127) is None  # 254 bytes


def test_a_path_too_long_in_all_is_a_named_error(tmp_path: Path) -> None:
    """Every part fits, the whole path (folder and name) is longer than the OS opens: a named
    error (the OS stops at the first missing folder), the name shortened in the message."""
    name = "/".join(["a" * 250] * 16) + "/x.bin"
    assert is_contained_name(name)
    with pytest.raises(SplatFileError, match=r"buffers.0..uri 'a+\.\.\.'") as error:
        contained_file(tmp_path, name, tmp_path / "a.gltf", "buffers[0].uri")
    assert len(str(error.value)) < 600
