"""Gaussian Splatting for Blender.

Only `register()` and `unregister()` live here, and they import the Blender layer lazily, so
`import addon.core` works in a plain Python process without `bpy`.
"""


def register() -> None:
    from . import blender, cli_command
    blender.register()
    cli_command.register()  # blender -c gaussian_splatting <verb> (addon.cli)


def unregister() -> None:
    from . import blender, cli_command
    cli_command.unregister()
    blender.unregister()
