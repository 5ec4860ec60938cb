"""The interface between the trainer and a densification strategy (gsplat's `strategy/` idea).

A step of `Trainer.train_step`, and where the strategy comes in:

    render_train -> loss -> backward -> strategy.after_backward -> Adam -> strategy.after_step

- `after_backward(params, info)`: the gradients of this step are in `info.grads`; the
  parameters are not yet updated. Collect statistics (screen-space gradients) and add the
  gradients of any regulariser the strategy owns (they act on parameters, not pixels).
- `after_step(params, info)`: Adam has run. Change the set of Gaussians: clone, split, prune,
  relocate, reset opacities, add noise. Return the change in their count.
- `prepare_initial(gaussians)`: the Gaussians made from the sparse points, as this strategy
  wants to start from (not called for Gaussians the caller passes in).
- `reset(count)`: the parameters were replaced (start, compaction): statistics start over.
- `after_check(step, value, count)`: a stopping check measured `value` dB (held-out PSNR, else
  training views) with `count` Gaussians at `step` (runs until done only).
- `recovering(step)`: True while the strategy's own disruption (an opacity reset) still lowers
  the views' PSNR: stopping checks then measure the disruption, not progress, and are not taken.
- `state_arrays()` / `load_state_arrays(data)`: what a checkpoint must hold to resume exactly.

Strategies edit `params` (a `GaussianParameters`) only through its row edits, so the Adam
moments stay aligned with the rows. Randomness comes from the trainer's generator (`rng`), so a
run is deterministic for a seed and resumes exactly from a checkpoint.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...cameras import Camera
from ...gaussians import Gaussians
from ..optimizer import GaussianParameters
from ..config import TrainConfig
from ..free_space import FreeSpace
from ..kernels import Gradients, TrainState


@dataclass
class StepInfo:
    """One training step, as a strategy sees it."""

    step: int                          # counts from 1
    camera: Camera
    state: TrainState                  # the forward pass (visibility)
    grads: Gradients                   # dL/d(parameters) of this step
    learning_rates: dict[str, float]   # this step's rates (`optimizer.LEARNING_RATES` keys)
    loss: float = float("nan")         # this step's training loss
    level: int = 0                     # how many times this step's image was halved
    view: int = -1                     # the dataset index of this step's view


class Strategy:
    """Base class: a strategy that never changes the Gaussians."""

    # Whether Adam moves only the Gaussians a step drew, unless `TrainConfig.sparse_adam` says.
    sparse_adam = False

    def __init__(self, config: TrainConfig, extent: float, rng: np.random.Generator,
                 free_space: FreeSpace | None = None,
                 cameras: list[Camera] | None = None) -> None:
        self.config = config
        self.extent = extent  # the scene's radius (`train.scene_extent`)
        self.rng = rng
        self.free_space = free_space  # where no Gaussian belongs (None: anywhere may hold one)
        self.cameras = list(cameras or [])  # the training views, at full size

    def in_free_space(self, params: GaussianParameters) -> np.ndarray:
        """(N,) bool: the Gaussians whose centres lie in `free_space` (to prune)."""
        if self.free_space is None:
            return np.zeros(len(params), bool)
        return self.free_space.contains(params.params["means"])

    def prepare_initial(self, gaussians: Gaussians) -> Gaussians:
        return gaussians

    def reset(self, count: int) -> None:
        pass

    def after_backward(self, params: GaussianParameters, info: StepInfo) -> None:
        pass

    def after_step(self, params: GaussianParameters, info: StepInfo) -> int:
        return 0

    def after_check(self, step: int, value: float, count: int) -> None:
        pass

    def recovering(self, step: int) -> bool:
        return False

    @property
    def sizing(self) -> str:
        """How the count is changing, for progress displays ("growing", "settled"; "" when
        the strategy does not say)."""
        return ""

    def state_arrays(self) -> dict[str, np.ndarray]:
        return {}

    def load_state_arrays(self, data) -> None:
        pass
