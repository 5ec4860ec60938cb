"""The splats of a final render use as many threads as Blender renders with (bpy): a farm
worker limited with `blender -t N` (or Performance > Threads) keeps its splats to N too."""

from __future__ import annotations

import bpy_support as bs
from bpy_support import bpy  # the shared bpy import

from addon.blender.render.state import render_threads


def test_splat_threads_follow_blenders_render_threads():
    bs.reset_scene()
    scene = bpy.context.scene
    settings = scene.splat_render
    assert settings.threads == 0
    scene.render.threads_mode = "FIXED"
    for count in (1, 3, 7):
        scene.render.threads = count
        assert render_threads(scene, settings) == count
    settings.threads = 5                       # the add-on's own setting wins
    assert render_threads(scene, settings) == 5
    settings.threads = 0
    scene.render.threads_mode = "AUTO"
    assert render_threads(scene, settings) == scene.render.threads >= 1
