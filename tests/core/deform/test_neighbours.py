"""addon.core.deform.neighbours (native k-d tree) against the brute-force float64 twin
(tests/reference_deform.py): the same lists, index for index, on random clouds of every kind
the grid finds hard (uniform, clustered with far outliers, a row, a sheet, duplicates, exact
ties on a dyadic lattice, fewer points than k), their spatial layout and the cache."""

from __future__ import annotations

import numpy as np
import pytest

import reference_deform
from addon.core.deform import RestNeighbours, neighbourhoods, rest_neighbours, spatial_order


def clouds(rng) -> dict[str, np.ndarray]:
    n = int(rng.integers(200, 700))
    row = np.zeros((n, 3))
    row[:, 0] = np.sort(rng.uniform(-2, 2, n))
    sheet = np.column_stack([rng.uniform(-1, 1, (n, 2)), np.zeros(n)]) @ reference_deform.rotation_between(
        np.array([0.0, 0.0, 1.0]), rng.normal(size=3) / np.linalg.norm(rng.normal(size=3)))
    clustered = rng.normal(scale=0.05, size=(n, 3))
    clustered[: n // 20] = rng.uniform(-50, 50, (n // 20, 3))
    lattice = rng.integers(-4, 5, size=(n, 3)) * 0.125  # exact distances: ties everywhere
    duplicates = np.repeat(rng.normal(size=(n // 3, 3)), 3, axis=0)
    return {"uniform": rng.uniform(-3, 3, (n, 3)), "clustered": clustered, "row": row,
            "sheet": sheet, "lattice": lattice, "duplicates": duplicates}


@pytest.mark.parametrize("k", [1, 8, 17])
def test_the_nearest_are_the_brute_force_ones(rng, k):
    for name, points in clouds(rng).items():
        points = points.astype(np.float32)
        got = rest_neighbours(points, k, threads=2)
        want = reference_deform.neighbours(points, k)
        assert np.array_equal(got, want), f"{name}: {np.argwhere(got != want)[:5]}"


def test_fewer_points_than_k(rng):
    for n in (0, 1, 2, 5):
        points = rng.normal(size=(n, 3)).astype(np.float32)
        got = rest_neighbours(points, 8)
        assert got.shape == (n, 8)
        if n:
            assert np.array_equal(got, reference_deform.neighbours(points, 8))
        assert (got[:, max(n - 1, 0):] == -1).all()


def test_bad_input_is_a_clear_error(rng):
    points = rng.normal(size=(10, 3)).astype(np.float32)
    with pytest.raises(ValueError, match="k must be"):
        rest_neighbours(points, 0)
    with pytest.raises(ValueError, match="k must be"):
        rest_neighbours(points, 65)
    with pytest.raises(ValueError, match="shape"):
        rest_neighbours(points[:, :2])
    points[3, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        rest_neighbours(points)


def test_the_cache_keeps_lists_while_the_rest_positions_hold(rng):
    cache = RestNeighbours()
    points = rng.normal(size=(300, 3)).astype(np.float32)
    first = cache.get("a", points)
    assert cache.get("a", points.copy()) is first
    moved = points.copy()
    moved[17, 2] += 0.5
    again = cache.get("a", moved)
    assert again is not first
    assert np.array_equal(again.lists(), reference_deform.neighbours(moved, 8))
    cache.get("b", points)
    cache.keep_only({"b"})
    assert len(cache) == 1


def test_the_spatial_layout_holds_the_same_lists(rng):
    """`neighbourhoods` lays the rest positions out in Z-order; the rows it gives hold every
    Gaussian once, the rest positions and neighbour lists unchanged (`lists` gives them back
    by Gaussian), and neighbours lie closer in that order than in a random one."""
    for name, points in clouds(rng).items():
        points = points.astype(np.float32)
        hoods = neighbourhoods(points, 8)
        n = len(points)
        assert np.array_equal(np.sort(hoods.order), np.arange(n)), name
        assert np.array_equal(hoods.rest, points[hoods.order]), name
        assert np.array_equal(hoods.lists(), rest_neighbours(points, 8)), name
    points = rng.normal(size=(5000, 3)).astype(np.float32)
    hoods = neighbourhoods(points, 8)
    rows = np.arange(len(points))[:, None]
    assert np.median(np.abs(hoods.neighbours - rows)) < 100  # a random order: ~1700
    assert len(neighbourhoods(np.zeros((0, 3), np.float32))) == 0


def test_the_order_is_z_order(rng):
    """Points on an 8^3 lattice come out in Morton order of their cells."""
    cells = rng.permutation(np.stack(np.meshgrid(*[np.arange(8)] * 3, indexing="ij"), -1)
                            .reshape(-1, 3))
    order = spatial_order(cells.astype(np.float32))
    codes = [sum(((int(c[a]) >> b) & 1) << (3 * b + a) for a in range(3) for b in range(3))
             for c in cells[order]]
    assert codes == sorted(codes) and len(set(codes)) == 512
