"""Gaussian Splatting for Blender.

Only `register()` and `unregister()` live here, and they import the Blender layer lazily, so
`import addon.core` works in a plain Python process without `bpy`.
"""


def register() -> None:
    from . import blender
    blender.register()


def unregister() -> None:
    from . import blender
    blender.unregister()
