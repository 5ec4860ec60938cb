"""Everything that touches `bpy`: objects, operators, UI and render hooks."""


def register() -> None:
    pass


def unregister() -> None:
    pass
