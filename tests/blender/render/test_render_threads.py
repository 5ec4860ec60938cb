"""The splats of a final render use as many threads as Blender renders with (bpy): a farm
worker limited with `blender -t N` (or Performance > Threads) keeps its splats to N too; the
viewport and training in the background, by the same setting, leave the UI a core."""

from __future__ import annotations

import bpy_support as bs
from bpy_support import bpy  # the shared bpy import

from addon.blender.render.state import render_threads
from addon.blender.threads import scene_threads


def test_splat_threads_follow_blenders_render_threads():
    bs.reset_scene()
    scene = bpy.context.scene
    settings = scene.splat_render
    assert settings.threads == 0
    scene.render.threads_mode = "FIXED"
    for count in (1, 3, 7):
        scene.render.threads = count
        assert render_threads(scene) == count
    settings.threads = 5                       # the add-on's own setting wins
    assert render_threads(scene) == 5
    assert scene_threads(scene, beside_ui=False, override=2) == 2  # and an operator's over it
    settings.threads = 0
    scene.render.threads_mode = "AUTO"
    assert render_threads(scene) == scene.render.threads >= 1


def test_one_rule_for_every_path():
    """bpy.app.background: the viewport's and a background training's count is the final
    render's here (no UI to leave a core); the rule's arithmetic itself is tested in
    tests/core/test_thread_counts.py."""
    bs.reset_scene()
    scene = bpy.context.scene
    scene.render.threads_mode = "FIXED"
    scene.render.threads = 3
    assert bpy.app.background
    assert scene_threads(scene, beside_ui=True) == scene_threads(scene, beside_ui=False) == 3
    scene.render.threads_mode = "AUTO"
    assert scene_threads(scene, beside_ui=True) == scene.render.threads >= 1
