"""How sharp a frame is: the variance of its Laplacian (Pech-Pacheco et al. 2000).

Motion blur and defocus remove high frequencies, and the Laplacian is what is left of them: of
frames of the same scene a moment apart, the one with the larger variance is the sharper. The
measure compares frames of one video with each other; it has no absolute scale.
"""

from __future__ import annotations

import numpy as np


def laplacian_variance(gray: np.ndarray) -> float:
    """Variance of the 4-neighbour Laplacian of a 2D image (any numeric type), over its
    interior pixels."""
    g = np.asarray(gray, dtype=np.float32)
    if g.ndim != 2 or g.shape[0] < 3 or g.shape[1] < 3:
        raise ValueError(f"expected a 2D image of at least 3x3 pixels, got shape {g.shape}")
    lap = (g[:-2, 1:-1] + g[2:, 1:-1] + g[1:-1, :-2] + g[1:-1, 2:]) - 4.0 * g[1:-1, 1:-1]
    return float(lap.var(dtype=np.float64))
