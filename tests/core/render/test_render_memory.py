"""The renderer's working memory: bounded by what the tile lists need (stats["peak_bytes"], the
renderer's own count), and the buffers it keeps between frames (buffers.c) never carry anything
from one frame into the next."""

from __future__ import annotations

import numpy as np

from addon.core import native
from addon.core.render import renderer as api
from tests.scenes import fast_random_gaussians, random_camera, random_scene


def _same(a, b) -> bool:
    return all(np.array_equal(x, y) for x, y in zip(a, b))


def test_kept_buffers_change_nothing(rng):
    # Two scenes of different sizes, rendered alternately (each reuses the other's buffers),
    # then again after the buffers are released: every render equals the first of its kind.
    small = random_scene(rng, 2000, 97, 61, 1)
    big = (fast_random_gaussians(rng, 60_000, degree=2), random_camera(rng, 320, 240))
    first = {name: api.render(*scene) for name, scene in (("small", small), ("big", big))}
    for _ in range(2):
        for name, scene in (("big", big), ("small", small)):
            assert _same(api.render(*scene), first[name]), name
    native.splatcore().release_buffers()
    assert _same(api.render(*small), first["small"])
    native.splatcore().release_buffers()  # twice is fine


def test_peak_working_memory_is_what_the_lists_need(rng):
    # At most 132 bytes per Gaussian (the projected and the depth-sorted 64-byte splats side by
    # side while one is gathered into the other, and a 4-byte index), 4 per tile pair (the list)
    # and 4 per Gaussian while binning, and per tile 8 for its offset and 12 per binning chunk
    # (4 chunks per thread); nothing per pixel.
    gaussians, camera = fast_random_gaussians(rng, 50_000, degree=1), random_camera(rng, 640, 360)
    for threads in (1, 2):
        stats = api.render(gaussians, camera, threads=threads).stats
        tiles = (640 // 16) * (360 // 16 + 1)
        bound = 132 * len(gaussians) + 4 * stats["tile_pairs"] + (8 + 12 * 4 * threads) * tiles + 4096
        assert 0 < stats["peak_bytes"] <= bound, (stats["peak_bytes"], bound)
        assert stats["peak_bytes"] >= 64 * stats["visible"]  # the sorted splats at least
