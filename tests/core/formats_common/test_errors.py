"""formats_common/errors.py: every writer refuses NaN and Inf, and an OS error on reading or
writing (a folder that is a file, a missing file) is a SplatFileError naming the file, for every
format alike."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from addon.core import splat_io
from addon.core.formats import registry
from addon.core.formats_common.errors import SplatFileError
from scenes import random_gaussians

ENDINGS = sorted({fmt.endings[0] for fmt in registry.export_formats() if fmt.endings[0].startswith(".")})


@pytest.mark.parametrize("ending", ENDINGS)
def test_a_write_the_os_refuses_names_the_file(ending: str, tmp_path: Path, rng) -> None:
    (tmp_path / "a_file").write_bytes(b"")
    path = tmp_path / "a_file" / f"x{ending}"  # its "folder" is a file: NotADirectoryError
    with pytest.raises(SplatFileError, match="cannot write") as error:
        splat_io.save(random_gaussians(rng, 4, 1), path)
    assert error.value.path == str(path)


@pytest.mark.parametrize("ending", ENDINGS)
def test_every_writer_refuses_nan(ending: str, tmp_path: Path, rng) -> None:
    g = random_gaussians(rng, 4, 1)
    g.quats[2, 1] = np.nan
    with pytest.raises(SplatFileError, match=r"non-finite values in quats \(Gaussians.quats holds NaN"):
        splat_io.save(g, tmp_path / f"x{ending}")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("ending", [".ply", ".splat", ".spz", ".glb"])
def test_a_missing_file_is_a_splat_file_error(ending: str, tmp_path: Path) -> None:
    with pytest.raises(SplatFileError, match="cannot read"):
        splat_io.load(tmp_path / f"absent{ending}")
