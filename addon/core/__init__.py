"""Blender-free core: Gaussians, cameras, file formats and the renderer's Python API.

Nothing here imports `bpy`, so every module works in a plain Python process.
"""
