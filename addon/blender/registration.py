"""Register and unregister bpy classes, and the pointer properties that hang a PropertyGroup
on a type (`Object.splat`), so that doing it twice is harmless.

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



def add_pointer(owner, name: str, group) -> None:
    """`owner.<name>` (e.g. `Object.splat`) as a pointer to the PropertyGroup `group`, once."""
    if name not in owner.bl_rna.properties:
        setattr(owner, name, bpy.props.PointerProperty(type=group))


def remove_pointer(owner, name: str) -> None:
    if name in owner.bl_rna.properties:
        delattr(owner, name)
