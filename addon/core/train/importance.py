"""Each Gaussian's importance: how much of the training views it paints.

The importance of Gaussian i is the sum, over the views and their pixels, of its blending
weight alpha_i T_i (the share of the pixel it paints): the "global significance" of LightGaussian
(Fan et al. 2023) without its volume term, Mini-Splatting's importance (Fang and Wang 2024).
Blending weights do not depend on the colours, so a dark Gaussian counts with what it covers.

What it is for: pruning by contribution, not only by opacity. An opaque Gaussian hidden behind
others, or one a sliver wide, paints almost nothing; pruned while training goes on, what is
left takes over its few pixels (`strategies/auto.py`, `LargeImageStrategy`), and after training
`trainer.compact` prunes the same way.
"""

from __future__ import annotations

import numpy as np

from . import kernels
from ..cameras import Camera
from ..gaussians import Gaussians
from ..sh import SH_C0


def blending_weights(gaussians: Gaussians, cameras: list[Camera], *, background=None,
                     antialiased: bool = False, threads: int = 0) -> np.ndarray:
    """(N,) float64: per Gaussian, the sum over `cameras` and their pixels of alpha T.

    Exact, through the native backward pass: with dL/d(red) = 1 at every pixel, dL/d(SH DC red)
    is C0 times the summed weights wherever the red colour is not clamped at 0. So the weights
    are taken with every colour a neutral 0.5 (SH zero: never clamped); with its own colours a
    dark Gaussian read as weightless (compaction pruned 12,000 of 22,000 on cup, 2.1 dB held
    out). Each view's sums are the backward's float32 (identical for any thread count), added up
    in float64."""
    grey = Gaussians(gaussians.means, gaussians.log_scales, gaussians.quats,
                     gaussians.opacity_logits, np.zeros((len(gaussians), 1, 3), np.float32))
    total = np.zeros(len(grey))
    grads = kernels.Gradients.zeros_like(grey)
    d_rgb: dict[tuple[int, int], np.ndarray] = {}
    for camera in cameras:
        result, state = kernels.render_train(grey, camera, background=background,
                                             antialiased=antialiased, threads=threads)
        shape = result.rgb.shape[:2]
        if shape not in d_rgb:
            d_rgb[shape] = np.zeros(result.rgb.shape, np.float32)
            d_rgb[shape][..., 0] = 1.0
        kernels.backward(state, grey, d_rgb[shape], threads=threads, out=grads)
        total += grads.sh[:, 0, 0] / SH_C0
    return total


def least_important(weights: np.ndarray, fraction: float) -> np.ndarray:
    """(N,) bool: the Gaussians of smallest `weights` that together carry at most `fraction` of
    their total (the weightless ones always; ties in index order, so the choice is the same
    on every machine)."""
    weights = np.asarray(weights, np.float64)
    order = np.argsort(weights, kind="stable")
    cumulative = np.cumsum(weights[order])
    count = int(np.searchsorted(cumulative, fraction * weights.sum(), side="right"))
    mask = np.zeros(len(weights), bool)
    mask[order[:count]] = True
    return mask
