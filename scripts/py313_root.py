"""Official bpy 5.1+ (Python 3.13 wheels, which this machine's Python 3.11 cannot install) as a
place to run scripts: ../shared/real-blender's `py313` root filesystem, one venv per version
(`bpy313.sh VERSION` builds each once, about a minute; needs root, as its chroot does).

A process there sees only that root, so what it reads is staged under the root's /io first
(`Py313Root.stage_dir`, hard links where possible) and paths are translated both ways
(`inside`, `outside`). Used by scripts/test_installed_extension.py and
benchmarks/bench_blender_splats_cycles.py; it imports only the standard library.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
REAL_BLENDER = Path(os.environ.get("REAL_BLENDER_SCRIPTS", ROOT.parent / "shared" / "real-blender"))


class Py313Root:
    """bpy `version` in the py313 root; `python` is its interpreter's path inside the root."""

    def __init__(self, version: str):
        if os.geteuid() != 0:
            raise RuntimeError("needs root (../shared/real-blender chroots into its root "
                               "filesystem)")
        if not (REAL_BLENDER / "bpy313.sh").exists():
            raise RuntimeError(f"no {REAL_BLENDER / 'bpy313.sh'}")
        self.version = version
        self.root = Path(subprocess.run([str(REAL_BLENDER / "root.sh"), "py313"], check=True,
                                        capture_output=True, text=True).stdout.strip())
        self.python = f"/opt/bpy-{version}/bin/python"
        if not (self.root / self.python.lstrip("/")).exists():
            print(f"[bpy {version}] building the py313 root's venv (bpy313.sh {version})",
                  flush=True)
            subprocess.run([str(REAL_BLENDER / "bpy313.sh"), version], check=True)

    def stage_dir(self, prefix: str) -> Path:
        """A new empty folder under the root's /io (the caller removes it)."""
        io = self.root / "io"
        io.mkdir(parents=True, exist_ok=True)
        return Path(tempfile.mkdtemp(prefix=prefix, dir=io))

    def inside(self, path: Path) -> str:
        """A path under the root as the process there sees it."""
        return "/" + Path(path).resolve().relative_to(self.root.resolve()).as_posix()

    def outside(self, path: str) -> Path:
        return self.root / path.lstrip("/")

    def command(self, arguments: list[str], *, cwd: Path, env: dict[str, str]) -> list[str]:
        """The command line that runs `python ARGUMENTS` in the root, in `cwd` (a path under
        the root), with `env` (e.g. BLENDER_USER_RESOURCES, as inside paths) and nothing else
        of this environment."""
        # A mount namespace of its own: run.sh's mounts and unmounts of the shared root's /proc,
        # /sys and /dev then cannot pull them from under another run in the same root.
        private = (["unshare", "--mount", "--propagation", "private"]
                   if shutil.which("unshare") else [])
        return [*private, str(REAL_BLENDER / "run.sh"), "py313", "env", "-C", self.inside(cwd),
                *(f"{k}={v}" for k, v in env.items()), self.python, *arguments]


def link_or_copy(source: str, target: str) -> None:
    """shutil.copytree's copy_function: a hard link where the filesystem allows it."""
    try:
        os.link(source, target)
    except OSError:
        shutil.copy2(source, target)


def copy_tree(source: Path, target: Path) -> None:
    shutil.copytree(source, target, copy_function=link_or_copy,
                    ignore=shutil.ignore_patterns("__pycache__"))
