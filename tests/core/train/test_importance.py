"""Importance (addon/core/train/importance.py) and the pruning by it while training.

The blending weights are held against the float64 reference renderer's per-Gaussian sums of
alpha T (tests/reference.py) on fresh random scenes, 1e-5 relative (float32 compositing;
measured 3e-7 to 4e-7); `least_important` against its definition; the pruning in `LargeImageStrategy` against the
weights and `least_important` it is built from, and for equal results on 1 and 2 threads and
through a checkpoint."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import tests.reference as ref
from tests.scenes import random_camera, random_gaussians
from addon.core.colmap import read_colmap
from addon.core.train.dataset import ColmapDataset
from addon.core.train.importance import blending_weights, least_important
from addon.core.train.optimizer import GaussianParameters
from addon.core.train.strategies.auto import LargeImageStrategy
from addon.core.train.trainer import Trainer, TrainConfig

DEMO = Path(__file__).resolve().parents[3] / "examples" / "demo_colmap"


@pytest.fixture(scope="module")
def dataset() -> ColmapDataset:
    return ColmapDataset(read_colmap(DEMO), downscale=4)


def reference_weights(gaussians, cameras) -> tuple[np.ndarray, bool]:
    """Float64 per-Gaussian sums of alpha T over the cameras, and whether any pixel was within
    rounding of one of the renderer's discrete decisions (`ref.render`'s `ambiguous`)."""
    total, ambiguous = np.zeros(len(gaussians)), False
    for camera in cameras:
        out = ref.render_scene(gaussians, camera)
        total += out["weights"][:len(gaussians)]
        ambiguous |= bool(out["ambiguous"].any())
    return total, ambiguous


def test_blending_weights_match_the_float64_reference(rng) -> None:
    checked = 0
    for _ in range(20):  # fresh scenes until three are clear of ambiguous pixels
        gaussians = random_gaussians(rng, 40, 1)
        cameras = [random_camera(rng, 40, 30) for _ in range(3)]
        want, ambiguous = reference_weights(gaussians, cameras)
        if ambiguous:
            continue
        got = blending_weights(gaussians, cameras, threads=2)
        assert got.dtype == np.float64 and got.shape == (len(gaussians),)
        assert (want > 0).sum() >= 10  # the scene has Gaussians that paint pixels
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-7 * want.max())
        # the colours do not matter: a black Gaussian paints as much as a bright one
        gaussians.sh[::3] = -5.0
        assert np.array_equal(blending_weights(gaussians, cameras, threads=1), got)
        checked += 1
        if checked == 3:
            break
    assert checked == 3


def test_least_important_takes_the_smallest_up_to_the_fraction(rng) -> None:
    weights = np.array([5.0, 0.0, 1.0, 2.0, 0.0, 10.0])
    # sorted 0, 0, 1, 2, 5, 10 (total 18): 10 % is 1.8, which the first three stay within
    assert np.flatnonzero(least_important(weights, 0.1)).tolist() == [1, 2, 4]
    assert np.flatnonzero(least_important(weights, 0.0)).tolist() == [1, 4]  # weightless only
    assert least_important(weights, 1.0).all()
    assert not least_important(np.zeros(0), 0.5).any()
    for _ in range(20):
        w = rng.exponential(size=200) * (rng.random(200) < 0.9)
        fraction = rng.uniform(0.0, 0.3)
        mask = least_important(w, fraction)
        assert w[mask].sum() <= fraction * w.sum() * (1 + 1e-12)
        assert w[mask].max(initial=0.0) <= w[~mask].min()
        next_one = w[~mask].min()  # one more would cross the fraction
        assert w[mask].sum() + next_one > fraction * w.sum()


def large_config(**overrides) -> TrainConfig:
    # "auto" on these 120x90 images as on large ones, densifying and pruning early and often.
    base = dict(strategy="auto", auto_reference_above_pixels=5_000, steps=80, densify_from=20,
                densify_every=20, importance_from=40, importance_every=40,
                importance_prune_weight=0.02, sh_degree=1, sh_degree_interval=40, threads=2,
                seed=3)
    return TrainConfig(**(base | overrides))


def test_pruning_removes_the_least_important_on_the_training_views(dataset) -> None:
    trainer = Trainer(dataset, large_config())
    strategy = trainer.strategy
    assert isinstance(strategy, LargeImageStrategy)
    assert len(strategy.cameras) == len(dataset.train_indices)
    list(trainer.run(39))
    params = GaussianParameters(trainer.gaussians)
    weights = blending_weights(params.gaussians, strategy.cameras, threads=1)
    prune = least_important(weights, 0.02)
    assert 0 < prune.sum() < len(params)
    kept = {name: array[~prune].copy() for name, array in params.params.items()}
    assert strategy.prune_unimportant(params) == -int(prune.sum())
    for name, array in kept.items():
        assert np.array_equal(params.params[name], array), name


def test_pruning_is_scheduled_and_the_same_on_any_thread_count(dataset, tmp_path) -> None:
    a = Trainer(dataset, large_config())
    b = Trainer(dataset, large_config(threads=1))
    off = Trainer(dataset, large_config(importance_prune_weight=0.0))
    counts = [(x["gaussians"], y["gaussians"], z["gaussians"])
              for x, y, z in zip(a.run(), b.run(), off.run())]
    assert all(x == y for x, y, _ in counts)
    assert all(x == z for x, _, z in counts[:39])  # nothing before `importance_from`
    assert counts[39][0] < counts[39][2]  # step 40 pruned more than opacity alone does
    for name in a.params:
        assert np.array_equal(a.params[name], b.params[name]), name
    first = Trainer(dataset, large_config())
    list(first.run(50))
    first.save_checkpoint(tmp_path / "state.npz")
    resumed = Trainer.load_checkpoint(tmp_path / "state.npz", dataset)
    list(resumed.run())
    for name in a.params:
        assert np.array_equal(a.params[name], resumed.params[name]), name


def test_growth_settles_when_the_checks_stop_paying(dataset) -> None:
    config = large_config(auto_settle_db_per_doubling=0.5, auto_patience=2)
    strategy = Trainer(dataset, config).strategy
    strategy.level = 1
    strategy.after_check(500, 20.0, 1000)  # a coarse level: not judged, not recorded
    assert strategy.last_check is None
    strategy.level = 0
    strategy.after_check(1500, 24.0, 10_000)
    strategy.after_check(2000, 25.0, 20_000)  # one doubling, +1 dB: pays
    strategy.after_check(2500, 25.2, 40_000)  # +0.2 dB for a doubling: a miss
    assert strategy.misses == 1 and not strategy.settled
    strategy.after_check(3000, 25.3, 40_000)  # no growth: not judged
    assert strategy.misses == 1
    strategy.after_check(4000, 25.4, 56_569)  # half a doubling, +0.1 dB (< 0.25): settled
    assert strategy.settled and strategy.sizing == "settled" and not strategy.may_grow()
    # settled: densification only prunes
    params = GaussianParameters(Trainer(dataset, config).gaussians)
    strategy.reset(len(params))
    strategy.grad_accum[:] = 1.0
    strategy.grad_count[:] = 1
    assert strategy.densify_and_prune(params, prune_large=False) <= 0


def test_importance_pruning_may_replace_the_opacity_reset(dataset) -> None:
    common = dict(steps=60, opacity_reset_every=30, densify_until=200)
    ceiling = np.log(0.01 / 0.99)  # the logit a reset clamps every opacity to
    reset = Trainer(dataset, large_config(importance_replaces_reset=False, **common))
    assert reset.strategy.resets_opacity() and reset.strategy.recovering(31)
    list(reset.run())  # step 60 resets
    assert reset.params["opacity_logits"].max() <= ceiling + 1e-6
    replaced = Trainer(dataset, large_config(importance_replaces_reset=True, **common))
    assert not replaced.strategy.resets_opacity() and not replaced.strategy.recovering(31)
    list(replaced.run())
    assert replaced.params["opacity_logits"].max() > ceiling + 1.0
    off = Trainer(dataset, large_config(importance_replaces_reset=True, importance_prune_weight=0.0,
                                        **common))
    assert off.strategy.resets_opacity()  # no importance pruning: the reference's reset
