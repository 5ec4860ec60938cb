"""Threads for the add-on's native work in Blender, by the one rule of `core/threads.py`:
the scene's Gaussian Splats > Threads (`scene.splat_render.threads`, or an operator's own
Threads when set), 0 for as many as Blender renders with; beside the UI (the viewport, training
and bakes in the background) every core but one at most."""

from __future__ import annotations

import bpy

from ..core.threads import kernel_threads


def scene_threads(scene, *, beside_ui: bool, override: int = 0) -> int:
    """Threads for work on `scene`'s splats: `override` (an operator's Threads) if positive,
    else the scene's setting, else Blender's render threads; at most every core but one when
    `beside_ui` and Blender has a UI (not `--background`)."""
    settings = getattr(scene, "splat_render", None)
    setting = override or (int(settings.threads) if settings is not None else 0)
    blender = max(0, int(getattr(scene.render, "threads", 0)))
    return kernel_threads(setting, blender, beside_ui=beside_ui and not bpy.app.background)
