"""The one table of splat formats (`formats/registry.py`) and `splat_io` over it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from addon.core import splat_io
from addon.core.formats import registry
from addon.core.formats_common.errors import SplatFileError
from addon.core.gaussians import Gaussians


def scene(rng: np.random.Generator, degree: int = 3) -> Gaussians:
    k = (degree + 1) ** 2
    return Gaussians(rng.uniform(-2, 2, (40, 3)), rng.uniform(-5, -1, (40, 3)), rng.normal(size=(40, 4)),
                     rng.normal(0, 2, 40), rng.normal(0, 0.3, (40, k, 3)))


@pytest.mark.parametrize("name, expected", [
    ("a.ply", "3DGS PLY"), ("A.PLY", "3DGS PLY"), ("a.compressed.ply", "Compressed PLY (SuperSplat)"),
    ("a.splat", "antimatter15 .splat"), ("a.spz", "Niantic SPZ"), ("a.sog", "SOG bundle (PlayCanvas)"),
    ("meta.json", "SOG folder (PlayCanvas)"), ("lod-meta.json", "Streamed SOG (LOD set)"),
    ("a.glb", "glTF binary (KHR_gaussian_splatting)"), ("a.gltf", "glTF (KHR_gaussian_splatting)"),
])
def test_names_choose_formats(name: str, expected: str) -> None:
    assert registry.format_for(name).name == expected


def test_unknown_and_read_only(tmp_path: Path) -> None:
    for name in ("a.obj", "a", "other.json"):
        with pytest.raises(SplatFileError, match="unknown splat format") as error:
            splat_io.load(tmp_path / name)
        assert name in str(error.value)
    with pytest.raises(SplatFileError, match="cannot be written"):
        splat_io.save(Gaussians.empty(), tmp_path / "lod-meta.json")


def test_patterns_and_filter() -> None:
    patterns = registry.import_patterns()
    assert {".ply", ".splat", ".spz", ".sog", "meta.json", "lod-meta.json", ".glb", ".gltf"} <= set(patterns)
    assert set(splat_io.SUFFIXES) == set(patterns)
    glob = registry.filter_glob().split(";")
    assert "*.sog" in glob and "meta.json" in glob and "*.ply" in glob and len(glob) == len(set(glob))
    assert "lod-meta.json" not in registry.filter_glob(registry.export_formats())
    assert registry.file_extensions().split(";") == [".ply", ".splat", ".spz", ".sog", ".json", ".glb", ".gltf"]
    for fmt in registry.FORMATS:
        assert 0 <= fmt.max_sh_degree <= 3 and fmt.quantisation and fmt.can_read


@pytest.mark.parametrize("fmt", registry.export_formats(), ids=lambda f: f.name)
def test_every_writable_format_round_trips_through_the_table(rng: np.random.Generator, tmp_path: Path,
                                                            fmt: registry.SplatFormat) -> None:
    g = scene(rng)
    ending = fmt.endings[0]
    path = tmp_path / (ending if fmt.whole_name else "x" + ending)
    warnings = registry.write(g, path, antialiased=True)
    assert any("antialiased" in w for w in warnings) != fmt.stores_antialiased
    assert any("SH degree" in w for w in warnings) == (fmt.max_sh_degree < 3)
    back, antialiased = registry.read(path)
    assert antialiased == fmt.stores_antialiased
    assert len(back) == 40 and back.degree == fmt.max_sh_degree
    # Some formats reorder (Morton order): every Gaussian must come back near one of the originals.
    distances = np.linalg.norm(back.means[:, None, :] - g.means[None, :, :], axis=2)
    assert distances.min(axis=1).max() < 0.02
    assert len(set(distances.argmin(axis=1))) == 40
