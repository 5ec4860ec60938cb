"""Failing loudly: a final render that cannot compose its splats fails, and says why.

A render that cannot compose the splats must fail, never write an image that silently lacks
them. Python cannot cancel a render directly; Blender cancels one itself when the scene it
renders has no camera ("Cannot render, no camera": the render stops, nothing is written,
`bpy.ops.render.render` reports the error and returns CANCELLED, `blender -b -a` exits 1).
So a failure found when the render starts (render_init: a missing module, a bridge that is
not set up) clears the scene's camera for this render; `render_complete`/`render_cancel` put
it back. (Later, from frame_change_post, the camera has already been evaluated: a failure to
gather the splats is recorded there and fails the compose step.) That is done in background
renders only, which run on the main thread: an interactive render runs its handlers in the
render job's thread, where changing data is unsafe, so there the error is reported in the
window when the render ends and written files of failed frames are deleted.
A failure while composing (the helper engine, after the meshes rendered) is too late for the
camera: in background Blender it raises Blender's own break signal (SIGINT, what Ctrl+C does:
the render is cancelled and nothing is written; Blender ends the process on a second one,
exit code 2); where Blender has no such handler (the `bpy` module) the frame's written files
are deleted and `last_errors()` says why.

Before each frame renders, the files it would overwrite are moved aside (a rename, no copy):
a frame that fails gets its previous file back, and when the render ends every file it did not
write again is put back, so a failed render leaves the output folder as it was.
"""

from __future__ import annotations

import contextlib
import os

import bpy

from . import compositor_bridge as bridge
from .. import dependencies
from . import state
from ..registration import module_registration
from .layers import output_paths, wants_splat_passes, written_file


def _blender_handles_sigint() -> bool:
    """Blender's command-line break handler is installed (not Python's or the default one)."""
    import signal
    return bpy.app.background and signal.getsignal(signal.SIGINT) is None


def fail_render(scene, message: str, stage: str) -> None:
    """Make the current render of `scene` fail with `message` (see the module docstring).
    `stage`: "init" (render_init, before the meshes render: the camera can still stop it),
    "frame" (while Blender prepares the frame: recorded, the compose step fails with it) or
    "compose"."""
    if message not in state.current.errors:
        print(f"Gaussian splats: ERROR: {message}", flush=True)
        state.current.errors.append(message)
    if scene is None:
        return
    state.current.failed_frames.add(scene.frame_current)
    if not bpy.app.background or stage == "frame":
        return
    if stage == "init":
        if scene.name not in state.current.camera_restore and scene.camera is not None:
            state.current.camera_restore[scene.name] = scene.camera
            scene.camera = None
    elif _blender_handles_sigint():
        import signal
        os.kill(os.getpid(), signal.SIGINT)


def render_blockers(scene) -> list[str]:
    """Why the splats of `scene` cannot be composed into its final render (empty: they can)."""
    try:
        dependencies.require("splatcore", "Rendering Gaussian splats")
        if wants_splat_passes(scene):
            dependencies.require("OpenImageIO", "Splat Passes in multilayer EXR files "
                                                "(Properties > Render > Gaussian Splats; "
                                                "turn it off to render without them)")
    except dependencies.MissingModule as error:
        return [str(error)]
    found = bridge.problems(scene)
    if found:
        return [f"{'; '.join(found)}: set it up in Properties > Render > Gaussian Splats "
                f"(Set Up / Repair, or bpy.ops.splat.compositor_bridge()) before rendering"]
    return []


def last_errors() -> list[str]:
    """Why the current or last render failed (empty when it did not)."""
    return list(state.current.errors)


def set_aside_outputs(scene) -> None:
    """Before a frame renders: move the files it would overwrite aside (see the module note)."""
    for path in output_paths(scene):
        if path not in state.current.set_aside and os.path.isfile(path):
            head, name = os.path.split(path)
            aside = os.path.join(head, f".{name}.before-render")
            with contextlib.suppress(OSError):
                os.replace(path, aside)
                state.current.set_aside[path] = aside


def _put_back(path: str) -> bool:
    aside = state.current.set_aside.pop(path, None)
    if aside is None:
        return False
    with contextlib.suppress(OSError):
        os.replace(aside, path)
    return True


def settle_outputs() -> None:
    """When the render ends: files it wrote again stay (their previous copies go), the others
    come back."""
    for path, aside in list(state.current.set_aside.items()):
        if os.path.exists(path):
            with contextlib.suppress(OSError):
                os.remove(aside)
            state.current.set_aside.pop(path)
        else:
            _put_back(path)


def remove_failed_file(scene) -> None:
    """A frame whose splats failed: the file Blender just wrote lacks them, so it goes, and the
    file that was there before the render comes back."""
    path = written_file(scene)
    if path is not None:
        with contextlib.suppress(OSError):
            os.remove(path)
        restored = _put_back(path)
        print(f"Gaussian splats: removed {path}: its splats could not be composed"
              + ("; the previous file is back" if restored else ""), flush=True)


def report_in_window(message: str) -> None:
    """An interactive render failed: say so in the status bar and the Info editor."""
    try:
        bpy.ops.splat.report_render_error(message=message)
    except RuntimeError:
        pass  # the report is what the operator is for; bpy raises for ERROR reports
    return None


class SPLAT_OT_report_render_error(bpy.types.Operator):
    """Report why the last render could not compose its splats"""

    bl_idname = "splat.report_render_error"
    bl_label = "Splat Render Error"
    bl_options = {"INTERNAL"}

    message: bpy.props.StringProperty()

    def execute(self, context):
        self.report({"ERROR"}, self.message)
        return {"FINISHED"}


register, unregister = module_registration((SPLAT_OT_report_render_error,))
