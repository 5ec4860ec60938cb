"""glTF files from strangers (issue 29): buffer uris that leave the folder (any platform's form,
links, FIFOs, devices), node graphs that are not trees, counts beyond the limit in total,
bufferView-less accessors, transforms that overflow, JSON nested too deep. Each must be a
SplatFileError naming the file, in bounded time and memory; the memory and hang cases run in a
child with a 4 GiB address space (tests/limited.py)."""

from __future__ import annotations

import base64
import json
import os
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from addon.core.formats import gltf
from addon.core.formats_common import limits
from addon.core.formats_common.errors import SplatFileError
from limited import load_limited
from scripts import fuzz_hostile
from scenes import random_gaussians

posix_only = pytest.mark.skipif(sys.platform == "win32", reason="FIFOs and /dev/zero")


@pytest.fixture
def scene(tmp_path: Path, rng: np.random.Generator) -> tuple[Path, dict]:
    """`user/a.gltf` with its buffer in `user/a.bin`, and `outside/secret.bin` beside the folder."""
    user, outside = tmp_path / "user", tmp_path / "outside"
    user.mkdir(), outside.mkdir()
    gltf.save(random_gaussians(rng, 20, 1), user / "a.gltf")
    document = json.loads((user / "a.gltf").read_text())
    binary = base64.b64decode(document["buffers"][0]["uri"].split(",", 1)[1])
    (user / "a.bin").write_bytes(binary)
    (outside / "secret.bin").write_bytes(binary)  # valid data: a reader taking it would load it
    document["buffers"][0]["uri"] = "a.bin"
    return user / "a.gltf", document


def write(path: Path, document: dict) -> Path:
    path.write_text(json.dumps(document))
    return path


@pytest.mark.parametrize("uri", ["../outside/secret.bin", "%2e%2e/outside/secret.bin", "..\\outside\\secret.bin",
                                 "sub/../../outside/secret.bin", "/etc/passwd", "C:/outside/secret.bin",
                                 "C:secret.bin", "\\\\host\\share\\secret.bin", "\\Windows\\secret.bin",
                                 "file:///etc/passwd", "/dev/zero"])
def test_a_buffer_uri_never_leaves_the_folder(scene, uri: str) -> None:
    path, document = scene
    document["buffers"][0]["uri"] = uri
    with pytest.raises(SplatFileError, match="buffers.0..uri .*must be a relative path inside") as error:
        gltf.load(write(path, document))
    assert str(error.value).startswith(str(path))


@posix_only
@pytest.mark.parametrize("target", ["link_out", "fifo", "dev_zero", "folder"])
def test_a_buffer_uri_to_a_link_out_a_fifo_or_a_device_is_refused(scene, target: str) -> None:
    """The FIFO blocked forever and /dev/zero read until memory was gone (today: refused)."""
    path, document = scene
    user = path.parent
    if target == "link_out":
        os.symlink(user.parent / "outside" / "secret.bin", user / "b.bin")
    elif target == "fifo":
        os.mkfifo(user / "b.bin")
    elif target == "dev_zero":
        os.symlink("/dev/zero", user / "b.bin")
    else:
        (user / "b.bin").mkdir()
    document["buffers"][0]["uri"] = "b.bin"
    kind, text = load_limited(write(path, document), seconds=30)
    assert kind == "SplatFileError" and text.startswith(str(path)), (kind, text)
    assert "leads outside" in text or "not a regular file" in text


def test_shared_children_and_cycles_are_refused_at_once(scene) -> None:
    """40 nodes each listing the next 40 gave 2^40 paths: no end after 30 s (today: refused on
    the second visit of a node)."""
    path, document = scene
    document["nodes"] = [{"children": list(range(i + 1, 41))} for i in range(40)] + [{"mesh": 0}]
    document["scenes"] = [{"nodes": [0]}]
    kind, text = load_limited(write(path, document), seconds=30)
    assert kind == "SplatFileError" and "reached twice" in text, (kind, text)
    document["nodes"] = [{"children": [1]}, {"children": [0], "mesh": 0}]
    with pytest.raises(SplatFileError, match="node 0 is reached twice"):
        gltf.load(write(path, document))


def test_a_root_listed_many_times_is_refused(scene) -> None:
    path, document = scene
    document["scenes"] = [{"nodes": [0] * 200_000}]
    kind, text = load_limited(write(path, document), seconds=30)
    assert kind == "SplatFileError" and "reached twice" in text, (kind, text)


def test_an_accessor_of_a_billion_elements_without_a_buffer_view_is_refused(scene) -> None:
    path, document = scene
    for accessor in document["accessors"]:
        accessor.pop("bufferView")
        accessor["count"] = 10**9
    kind, text = load_limited(write(path, document), seconds=30)
    assert kind == "SplatFileError" and text.startswith(str(path)), (kind, text)
    for accessor in document["accessors"]:
        accessor["count"] = 20
    with pytest.raises(SplatFileError, match="without a bufferView"):
        gltf.load(write(path, document))


def test_the_limit_holds_for_all_instances_together(scene, monkeypatch: pytest.MonkeyPatch) -> None:
    """Two nodes showing one 20-Gaussian mesh load 40; a limit of 39 refuses them, before any
    buffer is read (the mesh is decoded once)."""
    path, document = scene
    document["nodes"] = [{"mesh": 0}, {"mesh": 0, "translation": [1, 0, 0]}]
    document["scenes"] = [{"nodes": [0, 1]}]
    write(path, document)
    assert len(gltf.load(path)) == 40
    monkeypatch.setattr(limits, "MAX_GAUSSIANS", 39)
    with pytest.raises(SplatFileError, match="declares 40 Gaussians in the scene's instances"):
        gltf.load(path)


def test_a_transform_overflowing_float32_is_refused(scene) -> None:
    path, document = scene
    document["nodes"] = [{"mesh": 0, "scale": [3e38, 3e38, 3e38]}]
    with pytest.raises(SplatFileError, match="non-finite|overflows"):
        gltf.load(write(path, document))
    document["nodes"] = [{"children": [1], "scale": [1e200] * 3}, {"mesh": 0, "scale": [1e200] * 3}]
    with pytest.raises(SplatFileError, match="overflows"):
        gltf.load(write(path, document))


def test_deeply_nested_json_is_a_named_error(scene) -> None:
    path, document = scene
    text = json.dumps(document).replace('"asset":', '"deep": ' + "[" * 100_000 + "]" * 100_000 + ', "asset":')
    path.write_text(text)
    start = time.process_time()
    with pytest.raises(SplatFileError, match="nests 100001 levels deep"):
        gltf.load(path)
    assert time.process_time() - start < 2.0


def test_one_file_named_by_many_buffers_is_read_once(scene) -> None:
    """A thousand buffers naming the same file share one read (memory stays the file's size)."""
    path, document = scene
    document["buffers"] = document["buffers"] * 1000
    write(path, document)
    buffers, read = gltf._buffers(path, document, None)
    assert len({id(b.obj) for b in buffers}) == 1 and read == (path.parent / "a.bin").stat().st_size
    assert len(gltf.load(path)) == 20


@pytest.mark.parametrize("uri, reason", [("a" * 300 + ".bin", "a part of 304 bytes"), ("a%00.bin", "NUL character"),
                                         ("a\ud800.bin", "not Unicode")])
def test_a_buffer_uri_no_file_system_holds_is_a_named_error(scene, uri: str, reason: str) -> None:
    """A uri the OS refuses (too long: it raised OSError Errno 36; an escaped NUL) names the
    file, the buffer and why."""
    path, document = scene
    document["buffers"][0]["uri"] = uri
    with pytest.raises(SplatFileError, match=f"buffers.0..uri .*{reason}.*; refused") as error:
        gltf.load(write(path, document))
    assert str(error.value).startswith(str(path))


def test_a_primitive_shown_by_166_nodes_is_refused_by_its_expansion(tmp_path: Path) -> None:
    """Issue 33: one 60k-Gaussian SH3 primitive shown by 166 nodes asked for 9.96M Gaussians
    (2.5 GB), each instance copied, then all concatenated. Refused before any buffer is decoded,
    naming the file, the declared size, the bound and how to raise it."""
    path = tmp_path / "a.glb"
    path.write_bytes(fuzz_hostile.glb_instances()["a.glb"])
    start = time.process_time()
    with pytest.raises(SplatFileError, match=r"a.glb: declares 9960000 Gaussians in the scene's instances of SH "
                                             r"degree 3 \(2241\.7 MiB loaded\) in \d+ bytes: \d+ bytes decoded per "
                                             r"byte read, more than the bound of 256 .*raise "
                                             r"Max Expansion in File > Import > Gaussian Splats, formats_common.limits"
                                             r".MAX_EXPANSION in a script, or set SPLAT_MAX_EXPANSION"):
        gltf.load(path)
    assert time.process_time() - start < 1.0


def test_instances_are_decoded_once_into_one_output(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """With the bound raised (a genuine instanced scene), the primitive is decoded once and each
    instance written into one preallocated output: the load peaks near the output's size, where
    copies then a concatenation held it twice."""
    path = tmp_path / "a.glb"
    path.write_bytes(fuzz_hostile.glb_instances(nodes=166, count=1000)["a.glb"])
    with pytest.raises(SplatFileError, match="bytes decoded per byte read"):
        gltf.load(path)
    monkeypatch.setattr(limits, "MAX_EXPANSION", 10_000)
    decoded = []
    original = gltf._primitive_gaussians
    monkeypatch.setattr(gltf, "_primitive_gaussians", lambda *a: decoded.append(1) or original(*a))
    tracemalloc.start()
    try:
        g = gltf.load(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    size = sum(a.nbytes for a in g.arrays().values())
    assert len(g) == 166_000 and g.degree == 3 and len(decoded) == 1
    assert peak < 1.3 * size, (peak, size)
    np.testing.assert_allclose(g.means[165_000:], g.means[:1000] + [165.0, 0.0, 0.0], atol=1e-4)
