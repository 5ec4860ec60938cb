"""Register and unregister bpy classes, and the pointer properties that hang a PropertyGroup
on a type (`Object.splat`), so that doing it twice is harmless.

A script may call `addon.register()` after the extension already did (or a test may), and
Blender raises on a second `register_class`; these helpers skip what is already there.
"""

from __future__ import annotations

from typing import Callable

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


def module_registration(classes=(), *, pointers=(), menus=(), handlers=()
                        ) -> tuple[Callable[[], None], Callable[[], None]]:
    """`register`, `unregister` for a module that registers `classes`, hangs PropertyGroups on
    types (`pointers`: (owner type, name, group) triples), appends draw functions to menus
    (`menus`: (menu type name, draw) pairs; a menu this Blender lacks is skipped) and adds
    application handlers (`handlers`: (`bpy.app.handlers` list name, function) pairs). Both
    are harmless to call twice."""

    def register() -> None:
        register_classes(classes)
        for list_name, handler in handlers:
            handler_list = getattr(bpy.app.handlers, list_name)
            if handler not in handler_list:
                handler_list.append(handler)
        for owner, name, group in pointers:
            add_pointer(owner, name, group)
        for menu_name, draw in menus:
            menu = getattr(bpy.types, menu_name, None)
            if menu is not None:
                menu.remove(draw)  # no-op unless registered before
                menu.append(draw)

    def unregister() -> None:
        for list_name, handler in handlers:
            handler_list = getattr(bpy.app.handlers, list_name)
            if handler in handler_list:
                handler_list.remove(handler)
        for menu_name, draw in menus:
            menu = getattr(bpy.types, menu_name, None)
            if menu is not None:
                menu.remove(draw)
        for owner, name, _group in pointers:
            remove_pointer(owner, name)
        unregister_classes(classes)

    return register, unregister


class GaussianSplatsPanel:
    """What the add-on's panels in the Properties editor share (a mixin, as Blender's own
    panels use): the editor, the region and the title; a panel adds its `bl_context` tab."""

    bl_label = "Gaussian Splats"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
