"""formats_common/limits.py: the Gaussian ceiling and the expansion bound, and how a user raises them."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from addon.core.formats_common import limits
from addon.core.formats_common.errors import SplatFileError

ROOT = Path(__file__).resolve().parents[3]


def test_gaussian_bytes_follow_the_layout() -> None:
    assert limits.gaussian_bytes(1, 0) == 4 * 14 and limits.gaussian_bytes(10, 3) == 10 * 4 * 59
    assert limits.gaussian_bytes(1, 4) == limits.gaussian_bytes(1, 3)  # degree 4 reads as 3


def test_the_expansion_bound_names_the_file_the_size_the_bound_and_how_to_raise_it(monkeypatch) -> None:
    limits.check_expansion("small.spz", 1000, 3, 1)  # under the slack: tiny files always pass
    limits.check_expansion("real.sog", 500_000, 2, 8_499_863)  # playbot's level 0 (8.9 per byte)
    with pytest.raises(SplatFileError, match=r"^bomb.spz: declares 1000000 Gaussians of SH degree 0 \(53\.4 MiB "
                                             r"loaded\) in 1000 bytes: 56000 bytes decoded per byte read, more "
                                             r"than the bound of 256 .*SPLAT_MAX_EXPANSION"):
        limits.check_expansion("bomb.spz", 1_000_000, 0, 1000)
    monkeypatch.setattr(limits, "MAX_EXPANSION", 100_000)
    limits.check_expansion("bomb.spz", 1_000_000, 0, 1000)


@pytest.mark.parametrize("value, expected", [("1000", 1000), ("", 256), ("x", 256), ("-5", 256)])
def test_the_environment_variable_raises_the_bound(value: str, expected: int) -> None:
    code = "from addon.core.formats_common import limits; print(limits.MAX_EXPANSION)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                         env={**os.environ, "SPLAT_MAX_EXPANSION": value}, check=True).stdout
    assert int(out) == expected
