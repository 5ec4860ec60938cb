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
