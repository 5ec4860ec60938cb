"""When a run until done is done: the PSNR gain per minute measured over a window of training
time, not between two neighbouring checks.

Held-out PSNR at full learning rates moves by tenths of a dB from one check to the next, and on
a scene whose steps are cheap two checks are seconds apart: the difference of two neighbouring
checks was mostly that noise, and two such differences below 0.1 dB a minute in a row came by
chance. The demo scene (120x90, 5 ms a step) stopped at step 3,500 (12 s, 22.3 dB) on a plateau
it leaves after a minute (measured over a minute, the same run stops at 29.3 dB after 170 s).
So the gain is the least-squares slope of PSNR against training time over the checks of the
last `window` seconds, and a run is not judged before its checks span a whole window.
"""

from __future__ import annotations

import numpy as np

Check = tuple[float, float]  # (training seconds, PSNR) at one stopping check


def gain_per_minute(checks: list[Check], window: float) -> float:
    """The slope (dB a minute) of PSNR against time over the checks of the last `window`
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
