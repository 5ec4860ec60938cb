"""The Gaussians container: a struct of float32 arrays, exactly as the native kernels take them.

Layout (see docs/conventions.md, "Gaussians in memory"):
    means           (N, 3)  world-space centres
    log_scales      (N, 3)  natural log of the per-axis standard deviations
    quats           (N, 4)  rotation as w, x, y, z; need not be normalised (normalised on use;
                            an all-zero quaternion means the identity rotation)
    opacity_logits  (N,)    opacity = sigmoid(logit)
    sh              (N, K, 3) spherical-harmonics coefficients, coefficient-major, RGB inner,
                            K = (degree + 1)^2, degree 0..3
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

SH_COUNTS = {1: 0, 4: 1, 9: 2, 16: 3}  # coefficients per channel -> SH degree


def sh_count(degree: int) -> int:
    """Coefficients per colour channel for an SH degree (1, 4, 9, 16)."""
    if degree not in (0, 1, 2, 3):
        raise ValueError(f"SH degree must be 0..3, got {degree}")
    return (degree + 1) ** 2


def sigmoid(logits) -> np.ndarray:
    """Opacities of opacity logits, float64: 1 / (1 + exp(-x)) (0 where exp overflows)."""
    x = np.asarray(logits, np.float64)
    with np.errstate(over="ignore"):
        return 1.0 / (1.0 + np.exp(-x))


def logit(opacity):
    """The opacity logit log(p / (1 - p)) of opacities in (0, 1): a float for a number, else a
    float64 array."""
    if np.ndim(opacity) == 0:
        p = float(opacity)
        return math.log(p / (1.0 - p))
    p = np.asarray(opacity, np.float64)
    return np.log(p / (1.0 - p))


def scales_of(log_scales) -> np.ndarray:
    """Standard deviations of log scales, float64: exp(x) (inf where exp overflows)."""
    x = np.asarray(log_scales, np.float64)
    with np.errstate(over="ignore"):
        return np.exp(x)


def log_scales_of(scales) -> np.ndarray:
    """Log scales of standard deviations, float64: log(s) (-inf at 0)."""
    s = np.asarray(scales, np.float64)
    with np.errstate(divide="ignore"):
        return np.log(s)


def _as_f32(name: str, value: object, tail: tuple[int, ...]) -> np.ndarray:
    array = np.ascontiguousarray(value, dtype=np.float32)
    if array.ndim != 1 + len(tail) or array.shape[1:] != tail:
        want = "(N" + "".join(f", {d}" for d in tail) + ")"
        raise ValueError(f"Gaussians.{name} must have shape {want}, got {array.shape}")
    return array


@dataclass(eq=False)
class Gaussians:
    means: np.ndarray
    log_scales: np.ndarray
    quats: np.ndarray
    opacity_logits: np.ndarray
    sh: np.ndarray

    def __post_init__(self) -> None:
        # Any array-like is accepted and stored as C-contiguous float32 (a copy only if needed).
        self.means = _as_f32("means", self.means, (3,))
        self.log_scales = _as_f32("log_scales", self.log_scales, (3,))
        self.quats = _as_f32("quats", self.quats, (4,))
        self.opacity_logits = _as_f32("opacity_logits", self.opacity_logits, ())
        sh = np.ascontiguousarray(self.sh, dtype=np.float32)
        if sh.ndim != 3 or sh.shape[2] != 3 or sh.shape[1] not in SH_COUNTS:
            raise ValueError(f"Gaussians.sh must have shape (N, K, 3) with K in 1, 4, 9, 16; got {sh.shape}")
        self.sh = sh
        n = len(self.means)
        for name in ("log_scales", "quats", "opacity_logits", "sh"):
            if len(getattr(self, name)) != n:
                raise ValueError(f"Gaussians.{name} has {len(getattr(self, name))} rows, means has {n}")

    @property
    def degree(self) -> int:
        """The SH degree the coefficients hold (0..3)."""
        k = self.sh.shape[1] if self.sh.ndim == 3 else None
        if k not in SH_COUNTS:
            raise ValueError(f"Gaussians.sh must have shape (N, K, 3) with K in 1, 4, 9, 16; "
                             f"got {self.sh.shape}")
        return SH_COUNTS[k]

    def __len__(self) -> int:
        return len(self.means)

    def __repr__(self) -> str:
        return f"Gaussians(n={len(self)}, degree={self.degree})"

    @classmethod
    def empty(cls, degree: int = 0) -> "Gaussians":
        k = sh_count(degree)
        return cls(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 4)), np.zeros(0), np.zeros((0, k, 3)))

    def arrays(self) -> dict[str, np.ndarray]:
        return {
            "means": self.means,
            "log_scales": self.log_scales,
            "quats": self.quats,
            "opacity_logits": self.opacity_logits,
            "sh": self.sh,
        }

    def subset(self, index: np.ndarray | slice) -> "Gaussians":
        """The Gaussians selected by a boolean mask, an index array or a slice (a copy)."""
        return Gaussians(**{name: a[index] for name, a in self.arrays().items()})

    def with_degree(self, degree: int) -> "Gaussians":
        """A copy truncated (or zero-padded) to another SH degree."""
        k = sh_count(degree)
        sh = np.zeros((len(self), k, 3), np.float32)
        keep = min(k, self.sh.shape[1])
        sh[:, :keep] = self.sh[:, :keep]
        return Gaussians(self.means, self.log_scales, self.quats, self.opacity_logits, sh)

    def copy(self) -> "Gaussians":
        return Gaussians(**{name: a.copy() for name, a in self.arrays().items()})

    def non_finite(self) -> str | None:
        """The name of the first array holding NaN or Inf, or None when all are finite."""
        for name, array in self.arrays().items():
            if not np.isfinite(array).all():
                return name
        return None
