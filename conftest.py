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
# CI sets this variable: there a missing ../shared/data fails the tests that need it, so CI can
# never pass by skipping them.
REQUIRE_SHARED_DATA = "SPLAT_REQUIRE_SHARED_DATA"
MISSING_SHARED_DATA = (
    "needs the real captures in ../shared/data beside the repository, which is missing: "
    "docs/development.md, 'Test data', says where each comes from")


@pytest.fixture
def rng(request: pytest.FixtureRequest) -> np.random.Generator:
    """A generator with a fresh seed each run (SPLAT_TEST_SEED=n repeats one); the seed is
    printed with any failure of the test that used it."""
    seed = int(os.environ.get("SPLAT_TEST_SEED", np.random.SeedSequence().entropy % (1 << 32)))
    request.node.user_properties.append(("seed", seed))
    print(f"random seed {seed} (repeat with SPLAT_TEST_SEED={seed})")
    return np.random.default_rng(seed)


def _require_shared_data() -> Path:
    """../shared/data, or a skip (a failure where SPLAT_REQUIRE_SHARED_DATA is set)."""
    if not SHARED_DATA.is_dir():
        if os.environ.get(REQUIRE_SHARED_DATA):
            pytest.fail(f"{SHARED_DATA} is missing and {REQUIRE_SHARED_DATA} is set: this test "
                        f"{MISSING_SHARED_DATA}")
        pytest.skip(MISSING_SHARED_DATA)
    return SHARED_DATA


@pytest.fixture
def shared_data() -> Path:
    """../shared/data, the real captures and splats. Without it the test is skipped (a fresh
    clone: `pytest -ra` sums these skips up in one line), or fails where CI sets
    SPLAT_REQUIRE_SHARED_DATA."""
    return _require_shared_data()


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo):
    """Skips for want of ../shared/data all report this file's place, so that `-ra` sums them
    up in one line ("SKIPPED [N] conftest.py: needs the real captures ...") instead of one a
    test."""
    report = yield
    if report.skipped and isinstance(report.longrepr, tuple) and \
            MISSING_SHARED_DATA in str(report.longrepr[2]):
        report.longrepr = (__file__, _require_shared_data.__code__.co_firstlineno - 1,
                          report.longrepr[2])
    return report
