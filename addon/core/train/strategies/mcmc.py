"""3DGS as Markov chain Monte Carlo (Kheradmand et al. 2024, "3D Gaussian Splatting as Markov
Chain Monte Carlo"), with the reference parameters (its code and gsplat's `MCMCStrategy`):

- no cloning by gradient and no pruning: from `densify_from` to `densify_until`, every
  `densify_every` steps, Gaussians with opacity at most `prune_opacity` or in the cameras'
  free space (`free_space`, not in the paper) ("dead") are
  **relocated** onto live ones drawn with probability proportional to opacity, and then
  `mcmc_growth` (5 %) more are **added** the same way, up to the budget `max_gaussians`;
  a Gaussian sampled n - 1 times becomes n copies whose opacity and scale are chosen so that
  together they look like the original (`relocation`, the paper's equation 9);
- **regularisers** on every step: `mcmc_opacity_reg` times the mean opacity and
  `mcmc_scale_reg` times the mean scale are added to the loss (their gradients here);
- **noise** on every step: each mean moves by `Sigma z` (z standard normal) times the position
  learning rate times `mcmc_noise_lr`, gated by `sigmoid(100 (1 - opacity - 0.995))` so only
  nearly transparent Gaussians wander;
- start: opacity `mcmc_initial_opacity` (0.5, the reference's for this strategy) and the 3-NN
  scales times `mcmc_initial_scale` (1, as the paper's code; gsplat's 0.1 left the demo scene
  at 6.7 dB after 200 steps where 1 reached 18.1 dB).

One difference: the relocated Gaussians' Adam moments are all zeroed (the sources and the
destinations), where the reference zeroes only the sources'.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from ...gaussians import Gaussians
from ..optimizer import GaussianParameters, logit
from ..kernels import position_noise
from .base import StepInfo, Strategy

MAX_COPIES = 51  # the reference caps the copies of one Gaussian per relocation here
_FLOAT32_EPS = float(np.finfo(np.float32).eps)


@lru_cache(maxsize=1)
def _relocation_coefficients() -> np.ndarray:
    """c[n, k] = sum over i = k+1..n of C(i-1, k) (-1)^k / sqrt(k+1), for n < MAX_COPIES + 1:
    the denominator of the scale update is then sum_k c[n, k] opacity'^(k+1)."""
    c = np.zeros((MAX_COPIES + 1, MAX_COPIES))
    for n in range(1, MAX_COPIES + 1):
        for k in range(n):
            c[n, k] = sum(math.comb(i - 1, k) for i in range(k + 1, n + 1)) * (-1) ** k / math.sqrt(k + 1)
    return c


def relocation(opacity: np.ndarray, scale: np.ndarray, copies: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Opacity and scale for each of `copies` Gaussians that replace one of `opacity`, `scale`
    (the paper's equation 9): 1 - (1 - o')^n = o, and the copies' summed footprint matches."""
    n = np.clip(np.asarray(copies, np.int64), 1, MAX_COPIES)
    o = np.asarray(opacity, np.float64)
    new_o = 1.0 - np.power(1.0 - o, 1.0 / n)
    powers = new_o[:, None] ** np.arange(1, MAX_COPIES + 1)[None, :]
    denominator = (_relocation_coefficients()[n] * powers).sum(axis=1)
    return new_o, (o / denominator)[:, None] * np.asarray(scale, np.float64)


class MCMCStrategy(Strategy):
    """Relocate dead Gaussians, grow by a fixed fraction to the budget, regularise, add noise."""

    # With dense Adam the regularisers' tiny gradients on Gaussians a view does not see become
    # full-size steps (Adam normalises them): sparse Adam measured better (TrainConfig).
    sparse_adam = True

    def prepare_initial(self, gaussians: Gaussians) -> Gaussians:
        c = self.config
        log_scales = gaussians.log_scales + np.float32(math.log(c.mcmc_initial_scale))
        return Gaussians(gaussians.means, log_scales, gaussians.quats,
                         np.full(len(gaussians), logit(c.mcmc_initial_opacity)), gaussians.sh)

    def after_backward(self, params: GaussianParameters, info: StepInfo) -> None:
        # In float32, in place, as the gradients they join (in float64 they took 0.7 ms of a
        # step at 17k Gaussians, now 0.08).
        c, n = self.config, len(params)
        if n == 0:
            return
        if c.mcmc_opacity_reg:  # d/d(logit) of reg * mean(sigmoid(logit))
            # sigmoid'(x) = e / (1 + e)^2 with e = exp(-|x|): no overflow, no cancellation
            e = np.exp(-np.abs(params.params["opacity_logits"]))
            d = e + np.float32(1.0)
            d *= d
            np.divide(e, d, out=e)
            e *= np.float32(c.mcmc_opacity_reg / n)
            info.grads.opacity_logits += e
        if c.mcmc_scale_reg:  # d/d(log s) of reg * mean(exp(log s)) over all 3N scales
            s = np.exp(params.params["log_scales"])
            s *= np.float32(c.mcmc_scale_reg / (3 * n))
            info.grads.log_scales += s

    def densifies_from(self) -> int:
        """The first step after which it relocates and grows."""
        return self.config.densify_from

    def after_step(self, params: GaussianParameters, info: StepInfo) -> int:
        c, step = self.config, info.step
        before = len(params)
        if self.densifies_from() < step < c.densify_until and step % c.densify_every == 0:
            self.relocate(params)
            self.grow(params)
        self.add_noise(params, info.learning_rates["means"] * c.mcmc_noise_lr)
        return len(params) - before

    def _sample(self, params: GaussianParameters, candidates: np.ndarray, count: int) -> np.ndarray:
        """`count` draws from `candidates`, with replacement, by opacity; the drawn rows get the
        opacity and scale of their share (`relocation`)."""
        opacity = params.opacities()
        weights = opacity[candidates]
        picked = candidates[self.rng.choice(len(candidates), count, p=weights / weights.sum())]
        copies = np.bincount(picked, minlength=len(params))[picked] + 1
        new_o, new_s = relocation(opacity[picked], np.exp(params.params["log_scales"][picked]), copies)
        new_o = np.clip(new_o, self.config.prune_opacity, 1.0 - _FLOAT32_EPS)
        params.params["opacity_logits"][picked] = logit(new_o)
        params.params["log_scales"][picked] = np.log(new_s)
        return picked

    def relocate(self, params: GaussianParameters) -> int:
        """Move the dead Gaussians onto live ones. Returns how many moved."""
        dead_mask = (params.opacities() <= self.config.prune_opacity) | self.in_free_space(params)
        dead, alive = np.flatnonzero(dead_mask), np.flatnonzero(~dead_mask)
        if len(dead) == 0 or len(alive) == 0:
            return 0
        picked = self._sample(params, alive, len(dead))
        for array in params.params.values():
            array[dead] = array[picked]
        for name in params.params:
            params.reset_moments(name, np.concatenate([dead, picked]))
        return len(dead)

    def growth(self) -> float:
        """The fraction of the count added at each densification step."""
        return self.config.mcmc_growth

    def grow(self, params: GaussianParameters) -> int:
        """Add `growth()` of the count more, up to the budget. Returns how many were added."""
        n = len(params)
        target = min(self.config.max_gaussians, int((1.0 + self.growth()) * n))
        count = max(0, target - n)
        if count == 0:
            return 0
        picked = self._sample(params, np.arange(n), count)
        params.append_and_keep([params.rows(picked)], np.ones(n, bool))
        return count

    def add_noise(self, params: GaussianParameters, scale: float) -> None:
        """Move nearly transparent Gaussians by covariance-shaped noise times `scale`
        (`kernels.position_noise`: native, one pass; as NumPy over (N, 3, 3) matrices it
        took 5.2 ms a step at 20k Gaussians on one thread, a sixth of the step)."""
        noise = self.rng.standard_normal((len(params), 3))
        p = params.params
        position_noise(p["means"], p["log_scales"], p["quats"], p["opacity_logits"], noise, scale,
                       threads=self.config.threads)
