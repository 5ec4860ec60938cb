"""Test set-up shared by every test: import paths, a private Blender config, fresh random seeds."""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))  # the shared helpers (reference, scenes, bpy_support...)

# bpy-level tests must not read or write the user's Blender configuration.
os.environ["BLENDER_USER_RESOURCES"] = tempfile.mkdtemp(prefix="splat-blender-user-")

SHARED_DATA = ROOT.parent / "shared" / "data"


@pytest.fixture
def rng(request: pytest.FixtureRequest) -> np.random.Generator:
    """A generator with a fresh seed each run (SPLAT_TEST_SEED=n repeats one); the seed is
    printed with any failure of the test that used it."""
    seed = int(os.environ.get("SPLAT_TEST_SEED", np.random.SeedSequence().entropy % (1 << 32)))
    request.node.user_properties.append(("seed", seed))
    print(f"random seed {seed} (repeat with SPLAT_TEST_SEED={seed})")
    return np.random.default_rng(seed)


@pytest.fixture
def shared_data() -> Path:
    """../shared/data, the real captures and splats (present in CI)."""
    if not SHARED_DATA.is_dir():
        pytest.fail(f"{SHARED_DATA} is missing: tests need ../shared beside the repository")
    return SHARED_DATA
