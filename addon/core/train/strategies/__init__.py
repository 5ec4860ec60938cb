"""Densification strategies: how the set of Gaussians grows, shrinks and moves while training.

`base.py` is the interface the trainer calls; each strategy is one file. To add one, write a
`Strategy` subclass in a new file and name it in `STRATEGIES`; `TrainConfig.strategy` picks it.
"""

from __future__ import annotations

import numpy as np

from ...cameras import Camera
from ..config import TrainConfig
from ..free_space import FreeSpace
from .auto import AutoStrategy, LargeImageStrategy
from .base import StepInfo, Strategy
from .default import DefaultStrategy
from .mcmc import MCMCStrategy

STRATEGIES: dict[str, type[Strategy]] = {"auto": AutoStrategy, "default": DefaultStrategy,
                                          "mcmc": MCMCStrategy}


def make_strategy(config: TrainConfig, extent: float, rng: np.random.Generator,
                  pixels: int = 0, free_space: FreeSpace | None = None,
                  cameras: list[Camera] | None = None) -> Strategy:
    """The strategy `config.strategy` names, for a scene of radius `extent` whose largest
    training image has `pixels` pixels ("auto" on images above
    `auto_reference_above_pixels`: `LargeImageStrategy`, the reference's densification),
    pruning what enters `free_space`; `cameras`: the training views (where importance is
    measured)."""
    try:
        kind = STRATEGIES[config.strategy]
    except KeyError:
        raise ValueError(f"unknown densification strategy {config.strategy!r}; "
                         f"choose one of {', '.join(STRATEGIES)}") from None
    if kind is AutoStrategy and 0 < config.auto_reference_above_pixels < pixels:
        kind = LargeImageStrategy
    return kind(config, extent, rng, free_space, cameras)


__all__ = ["STRATEGIES", "AutoStrategy", "DefaultStrategy", "LargeImageStrategy", "MCMCStrategy",
           "StepInfo", "Strategy", "make_strategy"]
