"""Streamed SOG (LOD) sets from strangers (issue 29): trees that repeat a leaf, runs beyond the
limit in total, chunk names in any platform's form or through links, deep JSON. Each must be a
SplatFileError naming lod-meta.json, in bounded time and memory."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from addon.core.formats import sog, sog_lod
from addon.core.formats_common import limits
from addon.core.formats_common.errors import SplatFileError
from limited import load_limited
from scripts import fuzz_hostile
from scenes import random_gaussians

pytest.importorskip("OpenImageIO")


@pytest.fixture
def lod(tmp_path: Path, rng: np.random.Generator) -> tuple[Path, dict]:
    """`user/lod-meta.json` over two chunks of 600 and 400 Gaussians; `outside/` holds a chunk."""
    user = tmp_path / "user"
    sog.save(random_gaussians(rng, 600, 0), user / "c0" / "meta.json")
    sog.save(random_gaussians(rng, 400, 0), user / "c1" / "meta.json")
    sog.save(random_gaussians(rng, 10, 0), tmp_path / "outside" / "meta.json")
    leaf = lambda f, o, c: {"lods": {"0": {"file": f, "offset": o, "count": c}}}  # noqa: E731
    index = {"version": 1, "lodLevels": 1, "filenames": ["c0/meta.json", "c1/meta.json"],
             "tree": {"children": [leaf(0, 0, 600), {"children": [leaf(1, 0, 100), leaf(1, 100, 300)]}]}}
    path = user / "lod-meta.json"
    path.write_text(json.dumps(index))
    assert len(sog_lod.load(path)) == 1000
    return path, index


def write(path: Path, index: dict) -> Path:
    path.write_text(json.dumps(index))
    return path


def test_a_leaf_repeated_50000_times_is_refused(lod) -> None:
    """A few kilobytes of tree asked for 30 million Gaussians (gigabytes); each Gaussian of a
    level is in one run, so repeated runs overlap and are refused before any chunk is decoded."""
    path, index = lod
    leaf = index["tree"]["children"][0]
    index["tree"] = {"children": [leaf] * 50_000}
    assert len(json.dumps(index)) < 4 << 20
    kind, text = load_limited(write(path, index), seconds=60)
    assert kind == "SplatFileError" and text.startswith(str(path)), (kind, text)
    assert "overlap" in text or "more than the limit" in text
    index["tree"] = {"children": [leaf] * 2}
    with pytest.raises(SplatFileError, match="overlap"):
        sog_lod.load(write(path, index))


def test_the_limit_holds_for_the_level_in_total(lod, monkeypatch: pytest.MonkeyPatch) -> None:
    path, _ = lod
    monkeypatch.setattr(limits, "MAX_GAUSSIANS", 999)
    with pytest.raises(SplatFileError, match="declares 1000 Gaussians at level 0, more than the limit of 999"):
        sog_lod.load(path)
    monkeypatch.setattr(limits, "MAX_GAUSSIANS", 599)  # the level fits, its biggest chunk does not
    with pytest.raises(SplatFileError, match="limit of 599"):
        sog_lod.load(path)


@pytest.mark.parametrize("name", ["../outside/meta.json", "C:/c0/meta.json", "C:c0/meta.json",
                                  "..\\outside\\meta.json", "\\\\host\\share\\meta.json", "/etc/passwd",
                                  "c0/../../outside/meta.json", "CON"])
def test_chunk_names_are_judged_on_every_platform(lod, name: str) -> None:
    path, index = lod
    index["filenames"][1] = name
    with pytest.raises(SplatFileError, match="bad chunk path") as error:
        sog_lod.load(write(path, index))
    assert str(error.value).startswith(str(path))
    index["filenames"][1] = "c1/meta.json"
    index["environment"] = name
    with pytest.raises(SplatFileError, match="bad chunk path"):
        sog_lod.load(write(path, index))


@pytest.mark.skipif(sys.platform == "win32", reason="links and FIFOs")
def test_a_chunk_through_a_link_out_or_a_fifo_is_refused(lod) -> None:
    path, index = lod
    user = path.parent
    os.symlink(user.parent / "outside", user / "out")
    index["filenames"][1] = "out/meta.json"
    with pytest.raises(SplatFileError, match="chunk 1 'out/meta.json': leads outside"):
        sog_lod.load(write(path, index))
    (user / "c2").mkdir()
    os.mkfifo(user / "c2" / "meta.json")
    index["filenames"][1] = "c2/meta.json"
    kind, text = load_limited(write(path, index), seconds=30)
    assert kind == "SplatFileError" and "not a regular file" in text, (kind, text)


def test_deeply_nested_lod_meta_is_a_named_error(lod) -> None:
    path, index = lod
    path.write_text(json.dumps(index)[:-1] + ', "deep": ' + "[" * 50_000 + "]" * 50_000 + "}")
    with pytest.raises(SplatFileError, match="lod-meta.json nests 50001 levels deep"):
        sog_lod.load(path)


def test_one_chunk_named_under_many_indices_is_read_once_and_runs_checked_together(lod) -> None:
    """20,000 indices naming c0 with a run each decoded c0 20,000 times (no end in a minute);
    the runs are now checked per chunk file, so they overlap and are refused at once."""
    path, index = lod
    index["filenames"] = ["c0/meta.json", "c1/meta.json"] + ["./c0/meta.json"] * 20_000
    leaf = lambda f: {"lods": {"0": {"file": f, "offset": 0, "count": 1}}}  # noqa: E731
    index["tree"] = {"children": [leaf(f) for f in range(2, 20_002)]}
    kind, text = load_limited(write(path, index), seconds=60)
    assert kind == "SplatFileError" and "overlap" in text, (kind, text)
    index["filenames"] = ["c0/meta.json", "./c0/meta.json", "c1/../c0/meta.json"]
    index["tree"] = {"children": [{"lods": {"0": {"file": f, "offset": 200 * f, "count": 200}}} for f in range(3)]}
    assert len(sog_lod.load(write(path, index))) == 600  # disjoint runs of one chunk: fine


def test_an_environment_chunk_declaring_10m_gaussians_is_refused_by_its_expansion(tmp_path: Path) -> None:
    """Issue 33: a LOD set's chunks inherit the SOG reader's bound (here its environment)."""
    for name, data in fuzz_hostile.lod_bomb().items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_bytes(data)
    with pytest.raises(SplatFileError, match="env/meta.json: declares .* bytes decoded per byte read"):
        sog_lod.load(tmp_path / "lod-meta.json")
