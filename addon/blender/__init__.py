"""Everything that touches `bpy`: objects, operators, UI and render hooks.

Each module below has its own `register()` / `unregister()`; they run in this order (and in
reverse on unregister). Importing them happens here, at register time, never at add-on import.
"""

from __future__ import annotations

import importlib
from types import ModuleType

MODULE_NAMES: list[str] = [
    # one line per module, dotted under this package, e.g. "splat_object", "io.operators"
    "properties", "sources.gather", "io.operators", "edit_operators",  # splat objects
    "io.sequence",  # splat sequences: the frame's file on the object (frame_change_pre)
    "io.colmap_import",  # COLMAP scenes: File > Import > COLMAP Scene
    "io.reconstruct",  # photos or a video: File > Import > Photos or Video
    "render.panel", "render.failures", "render.hooks", "viewport",  # rendering with meshes
    "job_runner",  # long jobs: status bar, Esc, splat.train_stop
    "train.operator", "train.scene_to_splats",  # training: splat.train, splat.bake_to_splats
    "train.panel",  # 3D View sidebar: start training, follow its progress
    "mesh_convert",  # splats to a textured mesh: splat.convert_to_mesh
    "blender_splats.convert",  # Blender 5.3's own splat point clouds: ownership, conversion
]


def _modules() -> list[ModuleType]:
    return [importlib.import_module(f"{__name__}.{name}") for name in MODULE_NAMES]


def register() -> None:
    for module in _modules():
        module.register()


def unregister() -> None:
    for module in reversed(_modules()):
        module.unregister()
