"""A strategy that sizes the model itself: 3DGS-MCMC (`mcmc.py`) whose Gaussian count follows
from the images instead of a budget.

The count grows as MCMC grows it (`auto_growth`, 10 %, more every `densify_every` steps, each
new Gaussian a share of a live one drawn by opacity; MCMC's own 5 % reached the count the scene
settles at later, and so a given PSNR later) only while growing still buys error on the
training views at the current resolution:

- the training loss is compared per view: each step's loss against the same view's loss the
  last time it was drawn (at the same resolution), as a relative fall per `densify_every` steps.
  Views differ in difficulty far more than a model improves in an interval, so comparing means
  over different draws of views would mostly measure which views were drawn;
- after an interval that grew the count by a fraction g, that fall must be at least
  `auto_gain_per_growth` x g (1 by default: 10 % more Gaussians must come with at least 10 %
  less loss in the interval). The fall includes what the optimiser finds with the Gaussians
  it has, so when even that is below the bar, more Gaussians do not pay: after
  `auto_patience` such intervals in a row the count settles;
- the image size sets a floor: below `auto_gaussians_per_pixel` (0.25) Gaussians per pixel of
  a training image at the current resolution, the count grows regardless of the loss, by
  `auto_floor_growth` (20 %) an interval. The loss rule alone is blind to the size: on larger
  images the loss holds more that a small model cannot explain yet (fine texture, noise), its
  relative fall per interval is small from the start, and the count settled where it settles
  on thumbnails (the demo scene at 480x360: ~5,000 Gaussians, held-out PSNR 21.4 dB and
  falling, where the reference recipe grew to 57,000 and reached 27.6 dB in the same CPU time;
  issue 25). Thumbnails settle above the floor (cup at 200x150: ~29,000 Gaussians for 30,000
  pixels; floor 7,500) and are unchanged;
- at a new resolution level (coarse to fine) it grows again: finer images show detail the
  coarse ones did not.

Dead Gaussians are still relocated every interval (MCMC's way of moving capacity to where the
error is), so a settled count keeps improving the fit. `max_gaussians` is a ceiling only.
Relocation and growth start at `auto_densify_from` (100), not MCMC's 500: growth is judged
as it goes, so there is no reason to wait (on cup it reached a given PSNR in less time).

On larger images (more than `auto_reference_above_pixels`, 100,000 pixels: about 365x275)
"auto" densifies as the reference does (`LargeImageStrategy`: clone and split by screen-space
gradient, `strategies/default.py`), whose count follows the image size by itself. Measured on
the demo scene at 480x360 (issue 25, one thread, CPU seconds on the shared 2-core machine):
this MCMC sizing, with the pixel floor, reached 23.4 dB held-out with 27,000 Gaussians at
82 s, the reference's densification 27.6 dB with 57,000 at 90 s and 28.9 dB at 159 s; on
thumbnails (cup 200x150, the demo at 120x90, beer 88x156) this strategy is the better one.
On the larger images it also prunes by contribution (`importance.py`) every 500 steps and
skips the opacity reset, so that the count is the scene's, not the ceiling's (issue 37: the
demo at 480x360 ended with 33,935 Gaussians and 29.82 dB held out, against 28.49 dB at best
with 93,516 and more).
"""

from __future__ import annotations

import numpy as np

from ..importance import blending_weights, least_important
from ..optimizer import GaussianParameters
from .base import StepInfo
from .default import DefaultStrategy
from .mcmc import MCMCStrategy


class AutoStrategy(MCMCStrategy):
    """MCMC that grows while added Gaussians still lower the training loss, then settles."""

    def densifies_from(self) -> int:
        return self.config.auto_densify_from

    growing_below_floor = False

    def growth(self) -> float:
        c = self.config
        return c.auto_floor_growth if self.growing_below_floor else c.auto_growth

    def reset(self, count: int) -> None:
        super().reset(count)
        if not hasattr(self, "growing"):  # the sizing state survives compaction's reset
            self.growing = True
            self.misses = 0  # judged intervals in a row whose growth did not pay
            self._new_level(-1)
            self.previous_count = 0  # the count at the last judgement
            self.pixels = 0  # of the last training image

    def _new_level(self, level: int) -> None:
        self.level = level  # the resolution level the views' losses are at
        self.view_loss: dict[int, tuple[int, float]] = {}  # view -> (step, loss) last drawn
        self.fall_sum, self.fall_steps = 0.0, 0  # this interval's relative falls per step

    def after_backward(self, params: GaussianParameters, info: StepInfo) -> None:
        super().after_backward(params, info)
        if info.level != self.level:  # new images: their losses are not comparable with before
            self._new_level(info.level)
            self.growing, self.misses = True, 0
        self.pixels = info.camera.width * info.camera.height
        last = self.view_loss.get(info.view)
        if last is not None and last[1] > 0 and info.step > last[0]:
            self.fall_sum += (last[1] - info.loss) / last[1] / (info.step - last[0])
            self.fall_steps += 1
        self.view_loss[info.view] = (info.step, info.loss)

    def grow(self, params: GaussianParameters) -> int:
        """Grow as MCMC does while the last growth paid for itself; never above the ceiling."""
        self._judge(len(params))
        if len(params) < self.floor():  # fewer than the image's pixels call for
            self.growing, self.misses = True, 0  # the loss rule judges from the floor on
            self.growing_below_floor = True
            try:
                return super().grow(params)
            finally:
                self.growing_below_floor = False
        return super().grow(params) if self.growing else 0

    def floor(self) -> int:
        """The count below which it grows whatever the loss does: `auto_gaussians_per_pixel`
        of the last training image's pixels (at its resolution level)."""
        return int(self.config.auto_gaussians_per_pixel * self.pixels)

    def _judge(self, count: int) -> None:
        """Weigh this interval's fall of the loss against the growth that preceded it."""
        interval = self.config.densify_every
        grown = count / self.previous_count - 1.0 if self.previous_count else 0.0
        # Too few views seen twice (an interval cut short by a change of resolution): no verdict.
        judged = self.fall_steps >= max(1, interval // 4)
        fall = self.fall_sum / max(self.fall_steps, 1) * interval
        self.previous_count = count
        self.fall_sum, self.fall_steps = 0.0, 0
        if not (judged and self.growing and grown > 0.0):
            return
        if fall >= self.config.auto_gain_per_growth * grown:
            self.misses = 0
        else:
            self.misses += 1
            self.growing = self.misses < self.config.auto_patience

    @property
    def sizing(self) -> str:
        return "growing" if self.growing else "settled"

    def state_arrays(self) -> dict[str, np.ndarray]:
        views = np.array([[view, step, loss] for view, (step, loss) in self.view_loss.items()],
                         np.float64).reshape(-1, 3)
        return {"auto_state": np.array([self.growing, self.misses, self.level, self.fall_sum,
                                        self.fall_steps, self.previous_count, self.pixels],
                                       np.float64),
                "auto_view_loss": views}

    def load_state_arrays(self, data) -> None:
        super().load_state_arrays(data)
        growing, misses, level, fall_sum, fall_steps, count, *pixels = data["auto_state"]
        self.pixels = int(pixels[0]) if pixels else 0
        self.growing, self.misses, self.level = bool(growing), int(misses), int(level)
        self.fall_sum, self.fall_steps = float(fall_sum), int(fall_steps)
        self.previous_count = int(count)
        self.view_loss = {int(v): (int(s), float(loss)) for v, s, loss in data["auto_view_loss"]}


class LargeImageStrategy(DefaultStrategy):
    """"auto" on images above `auto_reference_above_pixels`: the reference's densification
    (gradient-driven clone and split up to `densify_until`), which sizes the count to the
    image by itself, and two rules that keep the count the scene's rather than the ceiling's:

    - importance pruning (`importance_prune_weight` > 0): every `importance_every` steps from
      `importance_from`, at a densification step, before any opacity reset and not while the
      views recover from one, the Gaussians that together carry the smallest
      `importance_prune_weight` of the blending weight over the training views are pruned
      (`importance.py`): clones that ended up behind others, slivers, Gaussians only a view or
      two glimpse. Training goes on, so what remains takes over their pixels;
    - settling (`auto_settle_db_per_doubling` > 0, runs until done): growth stops once
      `auto_patience` stopping checks in a row, at full resolution, gained less held-out PSNR
      than that many dB per doubling of the count since the check before.

    A run until done stops on the held-out gain as any other."""

    step = 0

    def reset(self, count: int) -> None:
        super().reset(count)
        if not hasattr(self, "settled"):  # the sizing state survives pruning's reset
            self.settled = False
            self.misses = 0
            self.last_check: tuple[int, float] | None = None  # (count, value) at the last check
            self.level = 0  # the resolution level of the last step

    def after_backward(self, params: GaussianParameters, info: StepInfo) -> None:
        super().after_backward(params, info)
        self.level = info.level

    def after_step(self, params: GaussianParameters, info: StepInfo) -> int:
        self.step = info.step
        return super().after_step(params, info)

    def may_grow(self) -> bool:
        return not self.settled

    def resets_opacity(self) -> bool:
        c = self.config
        return not (c.importance_replaces_reset and c.importance_prune_weight > 0)

    def densify_and_prune(self, params: GaussianParameters, *, prune_large: bool) -> int:
        changed = super().densify_and_prune(params, prune_large=prune_large)
        if self.importance_due(self.step):
            changed += self.prune_unimportant(params)
        return changed

    def importance_due(self, step: int) -> bool:
        c = self.config
        return (c.importance_prune_weight > 0 and bool(self.cameras) and step >= c.importance_from
                and step % max(c.importance_every, 1) == 0 and not self.recovering(step))

    def prune_unimportant(self, params: GaussianParameters) -> int:
        """Prune the least important Gaussians (`importance.least_important`). Returns the
        count change."""
        c = self.config
        weights = blending_weights(params.gaussians, self.cameras, antialiased=c.antialiased,
                                   threads=c.threads)
        prune = least_important(weights, c.importance_prune_weight)
        if prune.all():  # never prune to nothing
            prune[np.argmax(weights)] = False
        before = len(params)
        params.append_and_keep([], ~prune)
        self.reset(len(params))
        return len(params) - before

    def after_check(self, step: int, value: float, count: int) -> None:
        """Judge the growth since the last check against the held-out gain (settling)."""
        c = self.config
        if c.auto_settle_db_per_doubling <= 0 or self.level != 0 or self.settled:
            return
        if self.last_check is not None and count > self.last_check[0] > 0:
            doublings = float(np.log2(count / self.last_check[0]))
            if value - self.last_check[1] < c.auto_settle_db_per_doubling * doublings:
                self.misses += 1
                self.settled = self.misses >= c.auto_patience
            else:
                self.misses = 0
        self.last_check = (count, value)

    @property
    def sizing(self) -> str:
        return "growing" if self.step < self.config.densify_until and not self.settled \
            else "settled"

    def state_arrays(self) -> dict[str, np.ndarray]:
        count, value = self.last_check or (0, float("nan"))
        return super().state_arrays() | {"large_state": np.array(
            [self.settled, self.misses, count, value, self.level], np.float64)}

    def load_state_arrays(self, data) -> None:
        super().load_state_arrays(data)
        if "large_state" in data:
            settled, misses, count, value, level = data["large_state"]
            self.settled, self.misses, self.level = bool(settled), int(misses), int(level)
            self.last_check = (int(count), float(value)) if count > 0 else None
