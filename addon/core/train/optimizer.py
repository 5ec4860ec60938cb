"""The trained parameters in the layout the kernels take, their Adam moments, and the row edits
(append, keep, reset) that densification strategies make.

The parameters are one `Gaussians`-shaped set of float32 arrays (`sh` is (N, K, 3), DC and the
higher bands together), so a step renders and differentiates them without a copy and Adam
updates the kernels' gradient arrays in place. The SH bands still get two learning rates
(3DGS's DC rate and its rate / 20 for the rest) in one kernel call: see
`GaussianParameters.adam_step`.
"""

from __future__ import annotations


import numpy as np

from . import kernels
from ..gaussians import Gaussians, logit, sigmoid  # noqa: F401 (logit: for the strategies)

PARAMETERS = ("means", "log_scales", "quats", "opacity_logits", "sh")
# Learning-rate keys: one per parameter array, except SH, which has one for DC, one for the rest.
LEARNING_RATES = ("means", "log_scales", "quats", "opacity_logits", "sh_dc", "sh_rest")


class GaussianParameters:
    """`params[name]` (float32, C-contiguous, in `Gaussians` layout) and `moments[name]`, the
    Adam pair (exp_avg, exp_avg_sq) shaped like it."""

    def __init__(self, gaussians: Gaussians) -> None:
        self.params = {name: array.copy() for name, array in gaussians.arrays().items()}
        self.moments = {name: (np.zeros_like(a), np.zeros_like(a)) for name, a in self.params.items()}
        # Beyond this many leading SH coefficients every moment is 0 (bands never rendered): see
        # `adam_step`. Row edits keep it true (new and reset rows have zero moments).
        self.sh_moved = 0

    def __len__(self) -> int:
        return len(self.params["means"])

    def opacities(self) -> np.ndarray:
        """sigmoid(opacity logits), (N,) float64."""
        return sigmoid(self.params["opacity_logits"])

    @property
    def gaussians(self) -> Gaussians:
        """The parameters as `Gaussians`: views, no copy (they change with the next step)."""
        return Gaussians(**self.params)

    def adam_step(self, grads: kernels.Gradients, lrs: dict[str, float], step: int, *,
                  rows: np.ndarray | None = None, sh_coeffs: int | None = None,
                  threads: int = 0) -> None:
        """One Adam update of every parameter from `grads` with the rates `lrs` (keys
        `LEARNING_RATES`). rows: (N,) bool, or None for all: only these Gaussians are updated,
        the others keep their parameters and moments (`kernels.adam_step`; the step's
        visible Gaussians make this gsplat's `visible_adam`).

        sh_coeffs: how many leading SH coefficients can have nonzero gradients (the rendered
        degree's (d + 1)^2; the backward gives 0 above it), or None: all. Coefficients beyond
        both it and every earlier step's have zero gradient and zero moments, where Adam leaves
        them exactly as they are: they are skipped (SH degree 0 of 3: 45 of 48 values a row)."""
        arrays = grads.arrays()
        count = self.params["sh"].shape[1]
        if sh_coeffs is None or sh_coeffs > count:
            sh_coeffs = count
        self.sh_moved = max(self.sh_moved, sh_coeffs)
        for name in PARAMETERS[:-1]:
            if self.params[name].size:
                m, v = self.moments[name]
                kernels.adam_step(self.params[name], arrays[name], m, v, lr=lrs[name], step=step,
                             rows=rows, threads=threads)
        # SH: one array, DC (the first 3 values of each row) at its own rate, the higher bands
        # at theirs: every element gets exactly the update a separate array would.
        if self.params["sh"].size:
            m, v = self.moments["sh"]
            kernels.adam_step(self.params["sh"], arrays["sh"], m, v, lr=lrs["sh_rest"], step=step,
                         rows=rows, lead=3, lead_lr=lrs["sh_dc"], used=3 * self.sh_moved,
                         threads=threads)

    # -- row edits (densification) ------------------------------------------------------------
    def rows(self, index: np.ndarray) -> dict[str, np.ndarray]:
        """Copies of the parameter rows at `index` (to edit and append)."""
        return {name: array[index].copy() for name, array in self.params.items()}

    def append_and_keep(self, new_rows: list[dict[str, np.ndarray]], keep: np.ndarray) -> None:
        """Keep the rows where `keep` is True, then append `new_rows` (with zero moments)."""
        for name in PARAMETERS:
            parts = [self.params[name][keep]] + [rows[name] for rows in new_rows]
            self.params[name] = np.ascontiguousarray(np.concatenate(parts))
            m, v = self.moments[name]
            added = sum(len(rows[name]) for rows in new_rows)
            pad = np.zeros((added,) + m.shape[1:], np.float32)
            self.moments[name] = (np.ascontiguousarray(np.concatenate([m[keep], pad])),
                                  np.ascontiguousarray(np.concatenate([v[keep], pad])))

    def reset_moments(self, name: str, index: np.ndarray | slice = slice(None)) -> None:
        """Zero the Adam moments of `name` at `index` (as 3DGS does when it replaces a tensor)."""
        for moment in self.moments[name]:
            moment[index] = 0.0

    # -- checkpoints ----------------------------------------------------------------------------
    def state_arrays(self) -> dict[str, np.ndarray]:
        arrays = {f"param_{k}": v for k, v in self.params.items()}
        arrays |= {f"m_{k}": m for k, (m, _) in self.moments.items()}
        arrays |= {f"v_{k}": v for k, (_, v) in self.moments.items()}
        return arrays

    @classmethod
    def from_state_arrays(cls, data) -> "GaussianParameters":
        """From `state_arrays()` as saved (also from checkpoints that stored SH as two arrays,
        `sh_dc` and `sh_rest`, before they were kept as one)."""
        def array(prefix: str, name: str) -> np.ndarray:
            if name == "sh" and f"{prefix}_sh" not in data:
                return np.concatenate([data[f"{prefix}_sh_dc"], data[f"{prefix}_sh_rest"]], axis=1)
            return np.ascontiguousarray(data[f"{prefix}_{name}"]).copy()

        out = cls.__new__(cls)
        out.params = {k: array("param", k) for k in PARAMETERS}
        out.moments = {k: (array("m", k), array("v", k)) for k in PARAMETERS}
        m, v = out.moments["sh"]
        moved = np.flatnonzero((m != 0).any(axis=(0, 2)) | (v != 0).any(axis=(0, 2)))
        out.sh_moved = int(moved[-1]) + 1 if len(moved) else 0
        return out
