"""`splatcore.checksum`: the F12 gather's test whether splat attributes changed (no bpy)."""

from __future__ import annotations

import numpy as np

from addon.core import native


def test_any_bit_and_any_few_neighbouring_bytes_change_the_checksum(rng):
    checksum = native.splatcore().checksum
    data = rng.integers(0, 256, 1003, dtype=np.uint8)  # a tail of 3 bytes past the last word
    base = checksum(data)
    assert base == checksum(data.copy()) and len(base) == 4
    for bit in range(8 * len(data)):
        changed = data.copy()
        changed[bit // 8] ^= np.uint8(1 << bit % 8)
        assert checksum(changed) != base, bit
    for start in range(0, len(data) - 24, 5):  # 24 bytes (192 bits) at once
        changed = data.copy()
        changed[start:start + 24] = rng.integers(0, 256, 24, dtype=np.uint8)
        if not np.array_equal(changed, data):
            assert checksum(changed) != base
    swapped = data.copy()  # the same words in another order
    swapped[:8], swapped[8:16] = data[8:16], data[:8]
    assert checksum(swapped) != base
    # (a zero byte added at the end is padding to it: the gather keys each attribute's size too)
    assert checksum(b"") == (0, 0, 0, 0)
