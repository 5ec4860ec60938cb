"""When a run until done is done: the PSNR gain per minute of *work*, measured over a window of
work, not between two neighbouring checks, and not on the wall clock.

Work, not time: the wall clock (and even the process's CPU time) depends on the machine's load,
so a rule on "dB per minute" of time stopped the same seeded run at a different step on a busy
machine than on an idle one. A step's work is modelled from what it computed (`step_work`: the
pixels of its image, the Gaussian-tile pairs it rasterised, the Gaussians it projected and
updated), in seconds of one core of the machine it was calibrated on; the same scene, seed and
settings then stop at the same step on any machine, at any load, with any thread count.

Over a window: held-out PSNR at full learning rates moves by tenths of a dB from one check to
the next, and on a scene whose steps are cheap two checks are seconds apart: the difference of
two neighbouring checks was mostly that noise, and two such differences below 0.1 dB a minute in
a row came by chance. The demo scene (120x90, 5 ms a step) stopped at step 3,500 (12 s, 22.3 dB)
on a plateau it leaves after a minute (measured over a minute, the same run stops at 29.3 dB
after 170 s). So the gain is the least-squares slope of PSNR against work over the checks of the
last `window` seconds of work, and a run is not judged before its checks span a whole window.
"""

from __future__ import annotations

import numpy as np

Check = tuple[float, float]  # (work seconds so far, PSNR) at one stopping check

# The cost model of one training step in seconds of one core (forward, loss, backward, Adam,
# strategy): least squares over 2,246 steps of the reference recipe on the demo scene at
# 480x360 (its coarse levels included), 1.6k to 73k Gaussians, one thread, process CPU time on
# this project's shared 2-core machine, 7 % median error (`benchmarks/bench_train.py` prints the
# fit after its curves). Its scale only sets what "a minute" of work is; the stop step does not
# depend on any measurement.
WORK_PER_PIXEL = 2.5e-7
WORK_PER_TILE_PAIR = 4.3e-7
WORK_PER_GAUSSIAN = 1.3e-7


def step_work(pixels: int, tile_pairs: int, gaussians: int) -> float:
    """The modelled cost of one training step, in seconds of one reference core: a function of
    what the step computed only, so the same for any load, clock and thread count."""
    return (WORK_PER_PIXEL * pixels + WORK_PER_TILE_PAIR * tile_pairs
            + WORK_PER_GAUSSIAN * gaussians)


def gain_per_minute(checks: list[Check], window: float) -> float:
    """The slope (dB a minute) of PSNR against work over the checks of the last `window`
    seconds, at least the last two (window 0: the last two checks' difference); NaN before two
    checks."""
    if len(checks) < 2:
        return float("nan")
    end = checks[-1][0]
    first = next((i for i, (t, _) in enumerate(checks) if t >= end - window), len(checks) - 2)
    t, p = np.array(checks[min(first, len(checks) - 2):], np.float64).T
    t = t - t.mean()
    return float(60.0 * (t @ (p - p.mean())) / max(t @ t, 1e-18))


def has_stalled(checks: list[Check], window: float, threshold: float) -> bool:
    """True when, at each of the last two checks, the checks then spanned at least `window`
    seconds and gained less than `threshold` dB a minute over it (a single slow stretch does not
    stop a run)."""
    if len(checks) < 3 or checks[-2][0] - checks[0][0] < window:
        return False
    return all(gain_per_minute(checks[:end], window) < threshold
               for end in (len(checks) - 1, len(checks)))
