"""`read_colmap` where pycolmap cannot load: in a child process of this Python.

A Linux distribution's Blender (Debian's 5.2) links the system's glog/gflags, beside which
pycolmap's own would close Blender (`errors.pycolmap_refusal`); that Blender's Python run as a
separate process loads pycolmap fine (`core.child`). `read_colmap_anywhere` reads in this
process when it can, else in a child that reads (and undistorts the photos into the cache, as
here) and hands the `ColmapScene` back pickled, through a file of a private temporary folder.
Progress comes back as JSON lines; a `progress` that raises ends the child (cancelling), and the
child's ColmapError comes back as a ColmapError with the same message.
"""

from __future__ import annotations

import json
import os
import pickle
import subprocess
import sys
import tempfile
from pathlib import Path

from ..atomic import atomic_path
from ..child import environment, module_here, python_command
from .cache import Progress
from .errors import ColmapError, pycolmap_refusal
from .reader import read_colmap
from .scene import ColmapScene


def read_colmap_anywhere(path: str | os.PathLike, image_folder: str = "images", *,
                         progress: Progress | None = None, **options) -> ColmapScene:
    """`read_colmap(path, image_folder, progress=progress, **options)`, in this process when
    pycolmap may load here, else in a child process."""
    if pycolmap_refusal() is None:
        return read_colmap(path, image_folder, progress=progress, **options)
    return read_colmap_in_a_process(path, image_folder, progress=progress, **options)


def read_colmap_in_a_process(path, image_folder: str = "images", *,
                             progress: Progress | None = None, **options) -> ColmapScene:
    report = progress or (lambda fraction, message: None)
    options = {k: str(v) if isinstance(v, os.PathLike) else v for k, v in options.items()}
    with tempfile.TemporaryDirectory(prefix="splat-colmap-") as scratch:
        result = Path(scratch) / "scene.pickle"
        request = {"path": str(path), "image_folder": str(image_folder), "options": options,
                   "out": str(result)}
        flags = getattr(subprocess, "CREATE_NO_WINDOW", 0)
        child = subprocess.Popen(python_command("core.colmap.outside", [json.dumps(request)]),
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                 stdin=subprocess.DEVNULL, env=environment(), encoding="utf-8",
                                 errors="replace", creationflags=flags)
        error = None
        try:
            for line in child.stdout:
                try:
                    message = json.loads(line)
                except ValueError:
                    continue
                if "progress" in message:
                    report(*message["progress"])  # may raise: cancelled
                elif "error" in message:
                    error = message["error"]
        finally:
            if child.poll() is None:
                child.kill()
            stderr = child.stderr.read()
            child.wait()
        if error is not None:
            raise ColmapError(error)
        if child.returncode != 0 or not result.is_file():
            tail = " ".join(stderr.split()[-40:])
            raise ColmapError(f"{path}: the COLMAP reader's process ended with status "
                              f"{child.returncode}" + (f": {tail}" if tail else ""))
        with open(result, "rb") as f:  # written by the child just now, into our private folder
            return _Unpickler(f).load()


class _Unpickler(pickle.Unpickler):
    """The child's classes are the add-on's under the package's folder name; here the package
    may be called otherwise (`bl_ext.user_default.gaussian_splatting` in Blender)."""

    def find_class(self, module: str, name: str):
        return super().find_class(module_here(module), name)


def main(argv: list[str]) -> int:
    """The child: one request (JSON) in, progress lines out, the scene pickled to its file."""
    request = json.loads(argv[0])

    def progress(fraction: float, message: str) -> None:
        print(json.dumps({"progress": [fraction, message]}), flush=True)

    try:
        scene = read_colmap(request["path"], request["image_folder"], progress=progress,
                            **request["options"])
    except (ValueError, OSError) as error:  # ColmapError, ImageError: the message says it all
        print(json.dumps({"error": str(error)}), flush=True)
        return 1
    with atomic_path(request["out"]) as tmp, open(tmp, "wb") as f:
        pickle.dump(scene, f, protocol=pickle.HIGHEST_PROTOCOL)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
