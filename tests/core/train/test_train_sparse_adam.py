"""TrainConfig.sparse_adam: each step's Adam update touches only the Gaussians that step drew
(gsplat's visible_adam), on the demo COLMAP scene at 120x90."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from addon.core.colmap import read_colmap
from addon.core.train.dataset import ColmapDataset
from addon.core.train.strategies import Strategy, make_strategy
from addon.core.train.trainer import Trainer, TrainConfig

DEMO = Path(__file__).resolve().parents[3] / "examples" / "demo_colmap"


@pytest.fixture(scope="module")
def dataset() -> ColmapDataset:
    return ColmapDataset(read_colmap(DEMO), downscale=4)


class RecordVisible(Strategy):
    """No densification; keeps each step's visibility."""

    def after_backward(self, params, info) -> None:
        self.visible = info.state.visible.copy()


def test_sparse_adam_moves_only_what_a_step_drew_and_learns(dataset) -> None:
    config = TrainConfig(steps=80, sh_degree=1, coarse_levels=0, sparse_adam=True, threads=2,
                         seed=5)
    strategy = RecordVisible(config, 1.0, np.random.default_rng(0))
    trainer = Trainer(dataset, config, strategy=strategy)
    trainer.train_step()  # moments are zero before a Gaussian's first update
    ever_drawn = strategy.visible.copy()
    start = trainer.evaluate(dataset.train_indices[:6]).psnr
    for _ in range(4):
        before = {k: v.copy() for k, v in trainer.params.items()}
        trainer.train_step()
        ever_drawn |= strategy.visible
        for name, array in trainer.params.items():
            moved = (array != before[name]).reshape(len(array), -1).any(axis=1)
            assert not moved[~strategy.visible].any(), name
            assert moved[strategy.visible].mean() > 0.5, name  # (a zero gradient does not move)
    for m, v in trainer.moments.values():
        assert not m[~ever_drawn].any() and not v[~ever_drawn].any()
    for _ in trainer.run():
        pass
    assert trainer.evaluate(dataset.train_indices[:6]).psnr > start + 2.0


class RecordVisibleDense(RecordVisible):
    sparse_adam = False


class RecordVisibleSparse(RecordVisible):
    sparse_adam = True


def _undrawn_moved(dataset, strategy_class, sparse_adam) -> bool:
    """Whether, over a few steps, a Gaussian that a step did not draw moved in that step."""
    config = TrainConfig(steps=80, sh_degree=1, coarse_levels=0, sparse_adam=sparse_adam,
                         threads=2, seed=5)
    strategy = strategy_class(config, 1.0, np.random.default_rng(0))
    trainer = Trainer(dataset, config, strategy=strategy)
    moved_undrawn = False
    for _ in range(6):
        before = trainer.params["means"].copy()
        trainer.train_step()
        moved = (trainer.params["means"] != before).any(axis=1)
        moved_undrawn |= bool(moved[~strategy.visible].any())
    return moved_undrawn


def test_the_strategy_chooses_sparse_adam_unless_the_config_says(dataset) -> None:
    assert make_strategy(TrainConfig(strategy="auto"), 1.0, np.random.default_rng(0)).sparse_adam
    assert make_strategy(TrainConfig(strategy="mcmc"), 1.0, np.random.default_rng(0)).sparse_adam
    assert not make_strategy(TrainConfig(strategy="default"), 1.0,
                             np.random.default_rng(0)).sparse_adam
    assert not _undrawn_moved(dataset, RecordVisibleSparse, None)
    assert _undrawn_moved(dataset, RecordVisibleDense, None)  # dense Adam: moments keep moving
    assert _undrawn_moved(dataset, RecordVisibleSparse, False)
    assert not _undrawn_moved(dataset, RecordVisibleDense, True)
