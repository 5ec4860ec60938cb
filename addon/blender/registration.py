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
    (`menus`: (menu, draw) pairs, the menu a type name (one this Blender lacks is skipped) or a
    function that picks the menu type when registering, as `job_runner.menu_parent`) and adds
    application handlers (`handlers`: (`bpy.app.handlers` list name, function) pairs). Both
    are harmless to call twice."""
    chosen: dict = {}  # draw -> the menu type a picking function chose for it

    def menu_of(menu, draw):
        if callable(menu):
            return chosen.get(draw)
        return getattr(bpy.types, menu, None)

    def register() -> None:
        register_classes(classes)
        for list_name, handler in handlers:
            handler_list = getattr(bpy.app.handlers, list_name)
            if handler not in handler_list:
                handler_list.append(handler)
        for owner, name, group in pointers:
            add_pointer(owner, name, group)
        for menu, draw in menus:
            if callable(menu):
                if chosen.get(draw) is not None:
                    chosen[draw].remove(draw)
                chosen[draw] = menu()
            menu = menu_of(menu, draw)
            if menu is not None:
                menu.remove(draw)  # no-op unless registered before
                menu.append(draw)

    def unregister() -> None:
        for list_name, handler in handlers:
            handler_list = getattr(bpy.app.handlers, list_name)
            if handler in handler_list:
                handler_list.remove(handler)
        for menu, draw in menus:
            menu = menu_of(menu, draw)
            if menu is not None:
                menu.remove(draw)
            chosen.pop(draw, None)
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
