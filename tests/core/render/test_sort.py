"""The renderer's depth sort (native/src/sort.c, run alone through splatcore.sort_keys) is NumPy's
stable argsort, for any thread count: the parallel radix sort's chunks each count and scatter
their own keys, and the result must not depend on how many there are."""

from __future__ import annotations

import numpy as np
import pytest
import splatcore

THREADS = [1, 2, 3, 7]


def _keys(rng: np.random.Generator, kind: str, n: int) -> np.ndarray:
    if kind == "depths":  # a scene's: within a factor of 10, many exactly equal
        keys = rng.uniform(0.5, 5.0, n).astype(np.float32)
        keys[rng.random(n) < 0.2] = 2.0
        return keys
    if kind == "all equal":
        return np.full(n, 3.25, np.float32)
    if kind == "undrawn":  # +inf for the Gaussians not drawn, few distinct finite keys
        keys = rng.integers(1, 6, n).astype(np.float32)
        keys[rng.random(n) < 0.3] = np.inf
        return keys
    if kind == "all inf":
        return np.full(n, np.inf, np.float32)
    if kind == "high bits":  # differ only in the exponent's top bits
        return np.float32(2.0) ** rng.choice(np.float32([-100, -10, 0, 10, 100]), n)
    if kind == "low bits":  # differ only in the last mantissa bits
        return np.float32(1.5) + np.float32(2**-23) * rng.integers(0, 4, n).astype(np.float32)
    if kind == "signed":  # the whole 32-bit range: negative, zero, -inf, +inf
        keys = (rng.standard_normal(n) * 10.0 ** rng.integers(-30, 30, n)).astype(np.float32)
        keys[rng.random(n) < 0.05] = 0.0
        keys[rng.random(n) < 0.02] = -np.inf
        keys[rng.random(n) < 0.02] = np.inf
        return keys
    raise ValueError(kind)


KINDS = ["depths", "all equal", "undrawn", "all inf", "high bits", "low bits", "signed"]


@pytest.mark.parametrize("n", [0, 1, 2, 37, 20_000, 150_000])
@pytest.mark.parametrize("kind", KINDS)
def test_sort_is_numpy_stable_argsort_for_any_thread_count(rng, kind, n):
    keys = _keys(rng, kind, n)
    want = np.argsort(keys, kind="stable")
    for threads in THREADS:
        order = np.full(n, -1, np.int32)
        finite = splatcore.sort_keys(keys, threads, order)
        assert finite == (keys != np.inf).sum()
        assert np.array_equal(order, want), f"{kind}, n={n}, threads={threads}"


def test_negative_zero_sorts_before_positive_zero():
    keys = np.float32([0.0, -0.0, 1.0, -0.0])
    order = np.empty(4, np.int32)
    splatcore.sort_keys(keys, 2, order)
    assert order.tolist() == [1, 3, 0, 2]


def test_sort_validates_its_inputs():
    order = np.empty(3, np.int32)
    with pytest.raises(ValueError, match="key 1 is NaN"):
        splatcore.sort_keys(np.float32([1.0, np.nan, 2.0]), 1, order)
    with pytest.raises(TypeError, match="keys must have dtype float32"):
        splatcore.sort_keys(np.zeros(3), 1, order)
    with pytest.raises(ValueError, match="out_order must have shape"):
        splatcore.sort_keys(np.zeros(4, np.float32), 1, order)
    with pytest.raises(TypeError, match="out_order must have dtype"):
        splatcore.sort_keys(np.zeros(3, np.float32), 1, np.empty(3, np.float32))
    read_only = np.empty(3, np.int32)
    read_only.setflags(write=False)
    with pytest.raises(ValueError, match="writable"):
        splatcore.sort_keys(np.zeros(3, np.float32), 1, read_only)
    with pytest.raises(ValueError, match="threads"):
        splatcore.sort_keys(np.zeros(3, np.float32), -1, order)
