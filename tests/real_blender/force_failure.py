"""Runs inside a real Blender before a render: makes the splat composite fail on purpose.

    blender -b FILE.blend --python force_failure.py -a -- KIND
    blender -b FILE.blend --python force_failure.py -- KIND --still OUT_PREFIX   (F12)

KIND: `module` (the native module cannot be imported: found when the render starts), `gather`
(the splats cannot be read: found while Blender prepares the frame), `compose` (the native
compositor fails after the meshes rendered). Every kind must fail the render: no file written,
a non-zero exit code.
"""

from __future__ import annotations

import importlib
import sys

ADDON = "bl_ext.user_default.gaussian_splatting"


def main(kind: str) -> None:
    hooks = importlib.import_module(ADDON + ".blender.render.hooks")
    dependencies = importlib.import_module(ADDON + ".blender.dependencies")
    if kind == "module":
        real = dependencies.require

        def require(module, feature):
            if module == "splatcore":
                raise dependencies.MissingModule(f"{feature} needs 'splatcore' (forced)")
            real(module, feature)
        dependencies.require = require
    elif kind == "gather":
        def broken(*args, **kwargs):
            raise ValueError("forced: a bad splat object")
        hooks.capture_frame = broken
    elif kind == "compose":
        def broken(*args, **kwargs):
            raise RuntimeError("forced: the native compositor failed")
        hooks.compose = broken
    else:
        raise SystemExit(f"unknown failure kind {kind!r}")
    print(f"force_failure: {kind}", flush=True)


if __name__ == "__main__":
    args = sys.argv[sys.argv.index("--") + 1:]
    main(args[0])
    if "--still" in args:  # F12 (render_still.py) with the failure in place
        import os
        sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
        import render_still
        code = render_still.main(args[args.index("--still") + 1])
        sys.stdout.flush()
        os._exit(code)
