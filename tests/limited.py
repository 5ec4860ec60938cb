"""Load a splat file in a fresh Python with an address-space limit and a time limit: how the
hardening tests show that a hostile file gives a named error, not a MemoryError, a hang or a
crash of the test run (Linux and macOS: resource limits)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

_CHILD = r"""
import json, resource, sys
limit = int(sys.argv[1])
if limit:
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
sys.path.insert(0, sys.argv[2])
from addon.core.formats_common.errors import SplatFileError
try:
    exec(sys.argv[3])
    out = {"kind": "loaded", "text": str(result)}
except SplatFileError as e:
    out = {"kind": "SplatFileError", "text": str(e)}
except BaseException as e:
    out = {"kind": type(e).__name__, "text": str(e)[:2000]}
print("RESULT " + json.dumps(out))
"""


def run_limited(code: str, *, memory_gib: float = 4.0, seconds: float = 60.0) -> tuple[str, str]:
    """Run `code` (which sets `result`) in a child; (kind, text): kind is "loaded",
    "SplatFileError", another exception's name, "timeout" or "died" (killed by a signal)."""
    limit = int(memory_gib * 2**30)
    try:
        done = subprocess.run([sys.executable, "-c", _CHILD, str(limit), str(ROOT), code],
                              capture_output=True, text=True, timeout=seconds,
                              env={**os.environ, "OPENBLAS_NUM_THREADS": "1"})
    except subprocess.TimeoutExpired:
        return "timeout", f"no answer in {seconds} s"
    for line in done.stdout.splitlines():
        if line.startswith("RESULT "):
            out = json.loads(line[len("RESULT "):])
            return out["kind"], out["text"]
    return "died", f"exit {done.returncode}: {done.stderr[-2000:]}"


def load_limited(path: str | os.PathLike, **limits) -> tuple[str, str]:
    """`splat_io.load(path)` in a limited child; "loaded" comes with the count."""
    return run_limited(f"from addon.core import splat_io\nresult = len(splat_io.load({str(path)!r}))",
                       **limits)
