"""Gaussians gathered into one preallocated set: a reader that knows the total count and SH
degree before decoding (glTF instances, the runs of a LOD level) writes each part in place,
instead of holding every part and then a concatenated copy of them all (twice the memory).
"""

from __future__ import annotations

import numpy as np

from ..gaussians import Gaussians, sh_count

__all__ = ["Assembly"]


class Assembly:
    """`count` Gaussians of SH degree `degree`, filled part after part by `put`; parts of a lower
    degree are zero-padded, of a higher one truncated."""

    def __init__(self, count: int, degree: int) -> None:
        self.count, self.filled = count, 0
        self._arrays = Gaussians(np.empty((count, 3), np.float32), np.empty((count, 3), np.float32),
                                 np.empty((count, 4), np.float32), np.empty(count, np.float32),
                                 np.zeros((count, sh_count(degree), 3), np.float32))

    def put(self, part: Gaussians) -> None:
        end = self.filled + len(part)
        if end > self.count:
            raise ValueError(f"{end} Gaussians put into an assembly of {self.count}")
        out, at = self._arrays, slice(self.filled, end)
        out.means[at], out.log_scales[at], out.quats[at] = part.means, part.log_scales, part.quats
        out.opacity_logits[at] = part.opacity_logits
        keep = min(out.sh.shape[1], part.sh.shape[1])
        out.sh[at, :keep] = part.sh[:, :keep]
        self.filled = end

    def gaussians(self) -> Gaussians:
        """The assembled Gaussians (every one of them must have been put)."""
        if self.filled != self.count:
            raise ValueError(f"an assembly of {self.count} Gaussians holds {self.filled}")
        return self._arrays
