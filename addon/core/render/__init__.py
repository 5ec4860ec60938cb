"""Rendering splats: the renderer's Python API and composing splats with mesh renders."""
