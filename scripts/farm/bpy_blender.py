"""`blender` on the command line for a farm worker whose Blender is the official `bpy` module
(Blender 5.3 here, where only the module, not the executable, can be run): the arguments a
Flamenco worker and the farm test pass, carried out in order as Blender carries them out.

    python bpy_blender.py [-b] [-y] [--factory-startup] [FILE.blend] [--scene NAME]
        [--python-expr CODE] [--python FILE] [-o|--render-output PATH]
        [-F|--render-format FORMAT] [-f|--render-frame N|A..B] [-a] [-- SCRIPT ARGS]
    python bpy_blender.py --command extension install-file -r REPO -e ZIP
    python bpy_blender.py --version

Like Blender it exits 1 when a render fails (an engine's error, a Python error in a script),
writing nothing more; unlike Blender it refuses arguments it does not know instead of guessing.
Plain Python and bpy: it runs inside the worker's root, away from this project.
"""

from __future__ import annotations

import sys


def install_extension(bpy, args: list[str]) -> int:
    """`--command extension install-file -r REPO -e ZIP`: installed, enabled and saved in the
    user's preferences, as Blender's own command does."""
    if args[:2] != ["extension", "install-file"] or "-r" not in args or "-e" not in args:
        print(f"bpy_blender: unsupported command {args}", file=sys.stderr)
        return 2
    repo = args[args.index("-r") + 1]
    zip_path = args[-1]
    result = bpy.ops.extensions.package_install_files(filepath=zip_path, repo=repo,
                                                      enable_on_install=True)
    bpy.ops.wm.save_userpref()
    print(f"Installed \"{zip_path}\"" if result == {"FINISHED"} else f"failed: {result}")
    return 0 if result == {"FINISHED"} else 1


def render_frames(bpy, first: int, last: int) -> None:
    """Frames first..last written to the render output, as `-f` and `-a` render them (an
    animation render of that range: the same handlers and file names)."""
    scene = bpy.context.scene
    kept = scene.frame_start, scene.frame_end
    scene.frame_start, scene.frame_end = first, last
    try:
        result = bpy.ops.render.render(animation=True, scene=scene.name)
    finally:
        scene.frame_start, scene.frame_end = kept
    if result != {"FINISHED"}:   # "Cannot render, no camera" and the like: reported, then this
        raise RuntimeError(f"render of frames {first}..{last} {result}")


def frame_range(text: str) -> tuple[int, int]:
    """`N` or `A..B`, as Flamenco writes a task's frames."""
    first, _, last = text.partition("..")
    return int(first), int(last or first)


def run(bpy, argv: list[str]) -> int:
    script_args = argv[argv.index("--") + 1:] if "--" in argv else []
    argv = argv[:argv.index("--")] if "--" in argv else argv
    if argv[:1] == ["--version"]:
        print(f"Blender {bpy.app.version_string} (the bpy module)")
        return 0
    if argv[:1] == ["--command"]:
        return install_extension(bpy, argv[1:])
    if "--factory-startup" in argv:
        bpy.ops.wm.read_factory_settings()
    else:
        bpy.ops.wm.read_userpref()
    sys.argv = ["blender", *argv, "--", *script_args]   # what scripts see, as in Blender
    i = 0
    while i < len(argv):
        arg = argv[i]
        value = argv[i + 1] if i + 1 < len(argv) else None
        i += 1
        if arg in ("-b", "--background", "-y", "--enable-autoexec", "--factory-startup"):
            continue
        if arg in ("-a", "--render-anim"):
            scene = bpy.context.scene
            render_frames(bpy, scene.frame_start, scene.frame_end)
            continue
        if arg.endswith(".blend"):
            bpy.ops.wm.open_mainfile(filepath=arg, load_ui=False, use_scripts=True)
            continue
        if value is None:
            print(f"bpy_blender: {arg} needs a value", file=sys.stderr)
            return 2
        i += 1
        scene = bpy.context.scene
        if arg in ("-S", "--scene"):
            bpy.context.window.scene = bpy.data.scenes[value]
        elif arg == "--python-expr":
            exec(compile(value, "<--python-expr>", "exec"), {"__name__": "__main__"})
        elif arg in ("-P", "--python"):
            with open(value, encoding="utf-8") as file:
                code = compile(file.read(), value, "exec")
            exec(code, {"__name__": "__main__", "__file__": value})
        elif arg in ("-o", "--render-output"):
            scene.render.filepath = value
        elif arg in ("-F", "--render-format"):
            scene.render.image_settings.file_format = value
        elif arg in ("-f", "--render-frame"):
            render_frames(bpy, *frame_range(value))
        else:
            print(f"bpy_blender: unsupported argument {arg}", file=sys.stderr)
            return 2
    return 0


def main() -> int:
    import bpy
    try:
        return run(bpy, sys.argv[1:])
    except Exception as error:   # Blender prints the error and exits 1 on a failed render
        print(f"Error: {type(error).__name__}: {error}", flush=True)
        return 1


if __name__ == "__main__":
    sys.exit(main())
