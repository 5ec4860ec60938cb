"""The installed-extension matrix's own machinery (scripts/test_installed_extension.py,
scripts/py313_root.py), without any bpy: which stages a version runs, the per-version table,
the path translation into the py313 root and the command that enters it, and that a stage's
timeout ends the whole process group. The matrix itself runs in CI (.ci/run)."""

from __future__ import annotations

import importlib.util
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _load(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


matrix = _load("test_installed_extension")
py313 = _load("py313_root")


def test_each_line_runs_the_stages_it_can():
    assert matrix.stages_for("4.2.23") == ("install", "formats", "render", "colmap")
    assert matrix.stages_for("5.2.3") == matrix.stages_for("4.2.23")
    assert matrix.stages_for("5.3.0")[-1] == "blender_splats"
    assert matrix.stages_for("5.10.0")[-1] == "blender_splats"  # lines compare as numbers
    py313_lines = [v for v in matrix.BPY_VERSIONS if matrix.version_line(v) >= matrix.PY313_FROM]
    assert py313_lines == ["5.1.2", "5.2.3", "5.3.0"]


def test_the_table_shows_every_check_against_every_version():
    summary = [("4.2.23", "install the zip", True), ("5.3.0", "install the zip", True),
               ("5.3.0", "F12 CYCLES", False)]
    table = matrix.version_table(summary, ["4.2.23", "5.3.0"], {"4.2.23": 45.4}).splitlines()
    assert table[0].split() == ["check", "4.2.23", "5.3.0"]
    assert table[1].split()[-2:] == ["ok", "ok"]
    assert table[2].split()[-2:] == ["-", "FAIL"]       # not run there, failed here
    assert table[3].split()[-2:] == ["45", "-"]         # seconds; none for a version not timed


def test_paths_translate_both_ways_and_the_command_enters_the_root(tmp_path):
    where = object.__new__(py313.Py313Root)  # no root needed for the translation itself
    where.root, where.python = tmp_path / "py313", "/opt/bpy-5.3.0/bin/python"
    work = where.root / "io" / "run" / "work"
    work.mkdir(parents=True)
    assert where.inside(work) == "/io/run/work"
    assert where.outside("/io/run/work/a.png") == work / "a.png"
    command = where.command(["/io/run/x.py", "--flag"], cwd=work,
                            env={"BLENDER_USER_RESOURCES": "/io/run/user"})
    tail = command[command.index("py313") + 1:]
    assert tail == ["env", "-C", "/io/run/work", "BLENDER_USER_RESOURCES=/io/run/user",
                    "/opt/bpy-5.3.0/bin/python", "/io/run/x.py", "--flag"]
    assert command[command.index("py313") - 1].endswith("run.sh")


def test_a_timeout_ends_the_whole_process_group(tmp_path):
    marker = tmp_path / "grandchild.pid"
    script = f"sleep 60 & echo $! > {marker}; wait"  # a grandchild, as run.sh's chroot leaves
    start = time.perf_counter()
    output, code = matrix.run_process(["sh", "-c", script], dict(os.environ), tmp_path, 1.0)
    assert code == "timeout" and time.perf_counter() - start < 30
    pid = int(marker.read_text())
    for _ in range(50):  # the kill is asynchronous
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.1)
    else:
        raise AssertionError(f"the grandchild {pid} survived the timeout")
