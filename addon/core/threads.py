"""How many threads the add-on's native work runs on: one rule for training, final renders
(F12, -a), the viewport and mesh conversion (issue 37; the Blender side reads the settings in
`addon/blender/threads.py`).

- The setting (the scene's Gaussian Splats > Threads, or an operator's own Threads) N > 0:
  N threads.
- 0: as many as Blender renders with (Render > Performance > Threads: every core when Auto, the
  fixed count, or `blender -t N`); outside Blender, every core this process may use.
- Work that runs beside Blender's UI (the viewport's renders, training and bakes in the
  background) leaves the UI's main thread a core of its own: at most every core but one (issue
  25: with every core busy, a 10 ms timer in Blender ran a median 300 ms late). A final render,
  work on the main thread and work from a script or `--background` take the whole count.
Images and trained Gaussians are the same for any thread count.
"""

from __future__ import annotations

from .native import cpu_count


def kernel_threads(setting: int = 0, blender_threads: int = 0, *, beside_ui: bool = False,
                   cores: int | None = None) -> int:
    """Threads for native work (at least 1): `setting` if positive, else `blender_threads`
    if positive, else every core; beside a UI at most `cores` - 1 (`cores`: this process's,
    `native.cpu_count()`, unless given)."""
    if setting < 0 or blender_threads < 0:
        raise ValueError(f"thread counts must be >= 0, got {setting} and {blender_threads}")
    count = setting or blender_threads
    if beside_ui or not count:  # the cores only where they matter (F12's path stays short)
        cores = cpu_count() if cores is None else cores
        count = min(count or cores, cores - 1) if beside_ui else cores
    return max(1, count)
