"""The reconstruction's one exception type."""

from __future__ import annotations


class ReconstructionError(ValueError):
    """Photos or a video that cannot become a scene, or a workspace that cannot be written; the
    message names the file or folder and says why."""
