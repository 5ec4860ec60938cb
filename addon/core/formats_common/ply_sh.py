"""What both 3DGS `.ply` flavours (standard and compressed) share: the SH property names and
their channel-major file layout."""

from __future__ import annotations

import numpy as np

from ..gaussians import SH_COUNTS

F_REST_COUNTS = {3 * (k - 1): k for k in SH_COUNTS}  # 0, 9, 24, 45 -> K


def f_rest_names(count: int) -> list[str]:
    return [f"f_rest_{i}" for i in range(count)]


def sh_from_file_layout(dc: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """(N,3) DC and (N, 3*(K-1)) channel-major f_rest -> (N, K, 3) coefficient-major."""
    n, k = len(dc), rest.shape[1] // 3 + 1
    sh = np.empty((n, k, 3), np.float32)
    sh[:, 0, :] = dc
    sh[:, 1:, :] = rest.reshape(n, 3, k - 1).transpose(0, 2, 1)
    return sh
