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
    # and 4 per Gaussian while binning, and per tile 8 for its offset and 4 per binning chunk
    # (4 chunks per thread); nothing per pixel.
    gaussians, camera = fast_random_gaussians(rng, 50_000, degree=1), random_camera(rng, 640, 360)
    for threads in (1, 2):
        stats = api.render(gaussians, camera, threads=threads).stats
        tiles = (640 // 16) * (360 // 16 + 1)
        bound = 132 * len(gaussians) + 4 * stats["tile_pairs"] + (8 + 4 * 4 * threads) * tiles + 4096
        assert 0 < stats["peak_bytes"] <= bound, (stats["peak_bytes"], bound)
        assert stats["peak_bytes"] >= 64 * stats["visible"]  # the sorted splats at least


def test_binning_memory_per_thread_is_bounded_at_8k(rng):
    # Per binning chunk a count per tile (4 bytes: at 8K, 129,600 tiles, 0.5 MB), 4 chunks per
    # thread, but no more than 32 MiB of them beyond one chunk per thread: 64 threads at 8K
    # hold 64 chunks (33 MB), not 97 (where 100,000 Gaussians cap them). Before, with 97
    # chunks and 64-bit cursors beside the counts, 64 threads' peak was 69 MB above one
    # thread's (seed 1). compose_prepare bins without making any image.
    gaussians, camera = fast_random_gaussians(rng, 100_000, degree=0), random_camera(rng, 7680, 4320)
    options = dict(sh_degree=None, near=0.01, antialiased=False)
    peak = {t: native.compose_prepare(gaussians, camera, threads=t, **options)[1]["peak_bytes"]
            for t in (1, 64)}
    tiles = 480 * 270
    assert peak[64] - peak[1] <= 4 * 64 * tiles, peak
    assert peak[64] >= 4 * 64 * tiles, peak  # the chunks are there (a real bound)


def test_images_come_from_kept_memory_and_never_while_held(rng):
    # render() writes new images into memory the renderer keeps (buffers.c): a frame whose
    # images were dropped gives its pages to the next frame's (no page faults), and images
    # still held are never handed out again, however many frames follow.
    gaussians, camera = random_scene(rng, 3000, 640, 360, 1)
    other = random_scene(rng, 3000, 640, 360, 1)[0]
    def address(image: np.ndarray) -> int:
        return image.__array_interface__["data"][0]

    first = api.render(gaussians, camera)
    kept = [a.copy() for a in first]
    dropped = {address(first.rgb)}  # every frame's colour image, all dropped by the end
    for _ in range(3):
        again = api.render(other, camera)
        dropped.add(address(again.rgb))
        assert not any(np.shares_memory(a, b) for a in first for b in again)
    assert _same(first, kept)  # untouched by the frames after it
    del first, again
    assert address(api.render(gaussians, camera).rgb) in dropped
    native.splatcore().release_buffers()
    assert _same(api.render(gaussians, camera), kept)
