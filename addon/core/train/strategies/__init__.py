"""Densification strategies: how the set of Gaussians grows, shrinks and moves while training.

`base.py` is the interface the trainer calls; each strategy is one file. To add one, write a
`Strategy` subclass in a new file and name it in `STRATEGIES`; `TrainConfig.strategy` picks it.
"""

from __future__ import annotations

import numpy as np

from ..config import TrainConfig
from .auto import AutoStrategy
from .base import StepInfo, Strategy
from .default import DefaultStrategy
from .mcmc import MCMCStrategy

STRATEGIES: dict[str, type[Strategy]] = {"auto": AutoStrategy, "default": DefaultStrategy,
                                          "mcmc": MCMCStrategy}


def make_strategy(config: TrainConfig, extent: float, rng: np.random.Generator) -> Strategy:
    """The strategy `config.strategy` names, for a scene of radius `extent`."""
    try:
        kind = STRATEGIES[config.strategy]
    except KeyError:
        raise ValueError(f"unknown densification strategy {config.strategy!r}; "
                         f"choose one of {', '.join(STRATEGIES)}") from None
    return kind(config, extent, rng)


__all__ = ["STRATEGIES", "AutoStrategy", "DefaultStrategy", "MCMCStrategy", "StepInfo", "Strategy",
           "make_strategy"]
