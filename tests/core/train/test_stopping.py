"""The stop test of a run until done (`addon/core/train/stopping.py`): the gain per minute is a slope
over a window of training time, robust to the check-to-check noise of held-out PSNR."""

from __future__ import annotations

import numpy as np
import pytest

from addon.core.train.stopping import gain_per_minute, has_stalled


def _checks(seconds: np.ndarray, psnr: np.ndarray) -> list[tuple[float, float]]:
    return [(float(t), float(p)) for t, p in zip(seconds, psnr)]


def test_gain_is_the_least_squares_slope_over_the_window() -> None:
    t = np.arange(0.0, 300.0, 5.0)
    checks = _checks(t, 20.0 + 0.5 * t / 60.0)  # 0.5 dB a minute
    assert gain_per_minute(checks, 60.0) == pytest.approx(0.5, rel=1e-9)
    # Only the last window counts: flat for its last minute after a climb.
    late = _checks(t, np.where(t < 200.0, t / 10.0, 20.0))
    assert gain_per_minute(late, 60.0) == pytest.approx(0.0, abs=1e-9)
    assert gain_per_minute(late, 300.0) > 1.0
    # Window 0: the difference of the last two checks, per minute.
    assert gain_per_minute(_checks([0.0, 30.0, 60.0], [20.0, 21.0, 20.5]), 0.0) == pytest.approx(-1.0)
    assert np.isnan(gain_per_minute(_checks([0.0], [20.0]), 60.0))
    # A negative window (a script's setting) reads as 0, not as an error mid-run.
    assert gain_per_minute(_checks([0.0, 30.0, 60.0], [20.0, 21.0, 20.5]), -5.0) == pytest.approx(-1.0)


def test_noise_on_a_slow_climb_does_not_stop_a_run(rng) -> None:
    # Checks every 2.5 s (the demo scene's 500 steps) with 0.2 dB of noise (standard
    # deviation) on a climb of 1 dB a minute: neighbouring checks' differences fall below
    # 0.1 dB a minute almost half of the time, two in a row every few checks; a minute's slope
    # has a standard deviation of 0.14 dB a minute, so 0.1 is 6 of them below the true 1.0.
    t = np.arange(2.5, 600.0, 2.5)
    psnr = 22.0 + t / 60.0 + rng.normal(0.0, 0.2, len(t))
    checks = _checks(t, psnr)
    naive = [has_stalled(checks[:n], 0.0, 0.1) for n in range(3, len(checks))]
    windowed = [has_stalled(checks[:n], 60.0, 0.1) for n in range(3, len(checks))]
    assert any(naive)
    assert not any(windowed)


def test_a_plateau_stops_once_a_window_is_covered(rng) -> None:
    t = np.arange(10.0, 400.0, 10.0)
    psnr = 30.0 + np.minimum(t, 150.0) / 30.0 + rng.normal(0.0, 0.02, len(t))
    stalled = [has_stalled(_checks(t[:n], psnr[:n]), 60.0, 0.1) for n in range(1, len(t) + 1)]
    first = stalled.index(True)
    assert all(stalled[first:])
    # Not before the checks of the last minute are all on the plateau (150 s on), at the second
    # such check in a row, and not before the checks span a minute.
    assert 210.0 <= t[first] <= 230.0
    assert not any(has_stalled(_checks(t[:n], np.full(n, 30.0)), 60.0, 0.1) for n in range(1, 7))
    assert has_stalled(_checks(t[:8], np.full(8, 30.0)), 60.0, 0.1)


# -- work, not time: the same stop step on an idle and on a busy machine ---------------------

from pathlib import Path  # noqa: E402

from addon.core.colmap import read_colmap  # noqa: E402
from addon.core.train import stopping  # noqa: E402
from addon.core.train import trainer as train_module  # noqa: E402
from addon.core.train.dataset import ColmapDataset  # noqa: E402
from addon.core.train.trainer import Trainer, TrainConfig  # noqa: E402

DEMO = Path(__file__).resolve().parents[3] / "examples" / "demo_colmap"


@pytest.fixture(scope="module")
def dataset() -> ColmapDataset:
    return ColmapDataset(read_colmap(DEMO), downscale=4)


def until_done(**overrides) -> TrainConfig:
    # A short run until done that stalls within its 160 steps: a check every 10 steps, a window
    # of a few checks' work, and a bar no real gain at this size clears for long.
    base = dict(steps=0, max_steps=160, stop_check_every=10, stop_window_seconds=0.05,
                stop_below_db_per_minute=1000.0, anneal_steps=10, sh_degree=1, threads=1, seed=5)
    return TrainConfig(**(base | overrides))


def test_step_work_counts_what_a_step_computed() -> None:
    assert stopping.step_work(0, 0, 0) == 0.0
    base = stopping.step_work(10_000, 5_000, 2_000)
    assert base > 0.0
    for more in ((20_000, 5_000, 2_000), (10_000, 10_000, 2_000), (10_000, 5_000, 4_000)):
        assert stopping.step_work(*more) > base


def test_the_stop_step_does_not_depend_on_the_clock(dataset, monkeypatch) -> None:
    idle = Trainer(dataset, until_done())
    idle_steps = [stats["step"] for stats in idle.run()]
    assert idle.converged and idle.step < 160  # the rule stopped it, not the step limit
    assert idle.checks[-1][0] == pytest.approx(idle.work) and idle.work > 0.0
    # A machine 20 times slower (or as busy): every clock the trainer could read runs 20x.
    for name in ("perf_counter", "process_time", "monotonic", "time"):
        real = getattr(train_module.time, name)
        start = real()
        monkeypatch.setattr(train_module.time, name,
                            lambda real=real, start=start: start + 20.0 * (real() - start))
    busy = Trainer(dataset, until_done(threads=2))  # and another thread count
    busy_steps = [stats["step"] for stats in busy.run()]
    monkeypatch.undo()
    assert busy.seconds > idle.seconds  # the clock did run slow
    assert busy_steps == idle_steps and busy.anneal_from == idle.anneal_from
    assert busy.checks == idle.checks  # the same work and the same PSNR at every check


def test_a_run_until_done_ends_with_the_best_checked_state(dataset, monkeypatch) -> None:
    # The checks see 20, 22 (the best, at step 20), then worse: the run stops, and its state is
    # the one of step 20, not the last.
    values = iter([20.0, 22.0, 21.0, 20.5, 20.4, 20.3, 20.2])
    trainer = Trainer(dataset, until_done(stop_below_db_per_minute=1e9, stop_window_seconds=0.0,
                                          anneal_steps=10))
    real_evaluate = trainer.evaluate

    def evaluate(indices=None, **kwargs):
        result = real_evaluate(indices, **kwargs)
        if indices is not None and kwargs == {}:  # a stopping check
            result.psnr = next(values)
        return result

    monkeypatch.setattr(trainer, "evaluate", evaluate)
    kept = {}
    for stats in trainer.run():
        kept[stats["step"]] = trainer.gaussians.copy()
    assert trainer.converged and trainer.best[:2] == (20, 22.0)
    assert [p for _, p in trainer.checks] == [20.0, 22.0, 21.0, 20.5]
    for name, array in trainer.gaussians.arrays().items():
        assert np.array_equal(array, kept[20].arrays()[name]), name
    assert not np.array_equal(trainer.gaussians.means, kept[30].means)  # not the later state


def test_no_stopping_check_while_recovering_from_an_opacity_reset(dataset) -> None:
    # The reference densification resets opacities every `opacity_reset_every` steps until
    # `densify_until`; a check right after one measured the reset (the walkthrough read 4.1 dB
    # at step 3,000 and stopped). Such checks are not taken, others are.
    config = until_done(strategy="default", opacity_reset_every=40, densify_from=5,
                        densify_every=10, densify_until=120)
    trainer = Trainer(dataset, config)
    recovering = [s for s in range(1, 161) if trainer.strategy.recovering(s)]
    assert recovering == [s for r in (40, 80) for s in range(r, r + 11)]  # 120 is not a reset
    checked = []
    real_check = trainer._check
    trainer._check = lambda views: (checked.append(trainer.step), real_check(views))[1]
    for _ in trainer.run():
        pass
    assert checked and not set(checked) & set(recovering)


def test_the_reference_schedule_recovers_after_each_reset() -> None:
    from addon.core.train.strategies.default import DefaultStrategy

    strategy = DefaultStrategy(TrainConfig(), 1.0, np.random.default_rng(0))
    assert [s for s in (2999, 3000, 3500, 3501, 12000, 12500, 15000, 15500)
            if strategy.recovering(s)] == [3000, 3500, 12000, 12500]
