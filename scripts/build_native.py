"""STAND-IN, to be replaced at merge by the cross-compiling `scripts/build_native.py`.

It keeps only the interface that `scripts/build_extension.py` calls,
`build_native_wheel(platform, out_dir) -> Path`, and builds only this machine's platform
(linux-x64) the way the project always has: `pip wheel ./native` (one cp311-abi3 wheel).
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def build_native_wheel(platform: str, out_dir: Path) -> Path:
    """The `splatcore` wheel for Blender platform `platform` (e.g. "linux-x64"), in `out_dir`."""
    if platform != "linux-x64":
        raise NotImplementedError(
            f"the stand-in build_native.py builds linux-x64 only, not {platform}")
    out_dir.mkdir(parents=True, exist_ok=True)
    for old in out_dir.glob("splatcore-*.whl"):
        old.unlink()
    with tempfile.TemporaryDirectory() as scratch:  # keep build/ out of native/
        subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps",
                        "--no-build-isolation", "-w", str(out_dir), str(ROOT / "native")],
                       check=True, cwd=scratch)
    wheels = sorted(out_dir.glob("splatcore-*.whl"))
    if len(wheels) != 1:
        raise RuntimeError(f"expected one splatcore wheel in {out_dir}, found {wheels}")
    return wheels[0]
