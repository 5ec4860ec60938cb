"""Register and unregister bpy classes so that doing it twice is harmless.

A script may call `addon.register()` after the extension already did (or a test may), and
Blender raises on a second `register_class`; these helpers skip what is already there.
"""

from __future__ import annotations

import bpy


def register_classes(classes) -> None:
    for cls in classes:
        if not getattr(cls, "is_registered", False):
            bpy.utils.register_class(cls)


def unregister_classes(classes) -> None:
    for cls in reversed(tuple(classes)):
        if getattr(cls, "is_registered", False):
            bpy.utils.unregister_class(cls)

