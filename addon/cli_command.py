"""`blender -c gaussian_splatting <verb> ...` (Blender 4.2+): the verbs of `addon.cli`.

Registering costs nothing: `addon.cli` is imported when the command runs, not at add-on start.
It sits beside `cli.py`, above the Blender layer, and `addon.register()` registers it after that
layer's modules.
"""

from __future__ import annotations

import bpy

_handle = None


def _execute(argv: list[str]) -> int:
    from .cli import COMMAND_ID, main
    return main(argv, prog=f"blender -c {COMMAND_ID}")


def is_registered() -> bool:
    return _handle is not None


def register() -> None:
    global _handle
    if _handle is None and hasattr(bpy.utils, "register_cli_command"):  # 4.2+
        _handle = bpy.utils.register_cli_command("gaussian_splatting", _execute)


def unregister() -> None:
    global _handle
    if _handle is not None:
        bpy.utils.unregister_cli_command(_handle)
        _handle = None
