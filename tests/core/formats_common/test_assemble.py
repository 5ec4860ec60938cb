"""formats_common/assemble.py: parts written into one preallocated set."""

from __future__ import annotations

import numpy as np
import pytest

from addon.core.formats_common.assemble import Assembly
from scenes import random_gaussians


def test_parts_of_any_degree_fill_the_set_in_order(rng) -> None:
    a, b = random_gaussians(rng, 5, 1), random_gaussians(rng, 3, 3)
    out = Assembly(8, 2)
    out.put(a)
    out.put(b)
    g = out.gaussians()
    assert len(g) == 8 and g.degree == 2
    np.testing.assert_array_equal(g.means, np.concatenate([a.means, b.means]))
    np.testing.assert_array_equal(g.sh[:5], a.with_degree(2).sh)  # zero-padded
    np.testing.assert_array_equal(g.sh[5:], b.with_degree(2).sh)  # truncated


def test_too_many_or_too_few_is_an_error(rng) -> None:
    out = Assembly(4, 0)
    with pytest.raises(ValueError, match="5 Gaussians put into an assembly of 4"):
        out.put(random_gaussians(rng, 5, 0))
    out.put(random_gaussians(rng, 3, 0))
    with pytest.raises(ValueError, match="an assembly of 4 Gaussians holds 3"):
        out.gaussians()
