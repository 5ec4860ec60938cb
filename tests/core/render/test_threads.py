"""The image is bit-identical for any thread count (docs/guide/scripts.md). No reference
needed: the same scene rendered with threads = 1, 2, 3, 7 and 0 (all cores) must be equal."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from addon.core.render import renderer as api
from tests.scenes import fast_random_gaussians, random_camera, random_mesh_layer

THREADS = [1, 2, 3, 7, 0]


@pytest.fixture
def big_scene(rng):
    # ~20k Gaussians at 300x200 (19 x 13 tiles, partly covered edge tiles), SH degree 1.
    gaussians = fast_random_gaussians(rng, 20_000, degree=1)
    camera = random_camera(rng, 300, 200)
    return gaussians, camera


def _assert_identical(a, b, what):
    for name, x, y in zip(("rgb", "alpha", "depth"), a, b):
        assert np.array_equal(x, y), f"{name} differs ({what})"


def test_render_identical_for_any_thread_count(rng, big_scene):
    gaussians, camera = big_scene
    mesh_rgba, mesh_depth = random_mesh_layer(rng, camera.width, camera.height)
    for options in (dict(), dict(antialiased=True, background=np.float32([0.1, 0.5, 0.9]),
                                 mesh_rgba=mesh_rgba, mesh_depth=mesh_depth)):
        results = {t: api.render(gaussians, camera, threads=t, **options) for t in THREADS}
        assert results[1].alpha.mean() > 0.2  # a real workload
        assert not np.isnan(results[1].rgb).any()
        for t in THREADS[1:]:
            _assert_identical(results[1], results[t], f"threads={t} vs 1, {sorted(options)}")


def test_project_identical_for_any_thread_count(big_scene):
    gaussians, camera = big_scene
    first = api.project(gaussians, camera, threads=1)
    for t in THREADS[1:]:
        other = api.project(gaussians, camera, threads=t)
        for name in ("xy", "conic", "depth", "opacity", "rgb", "valid"):
            assert np.array_equal(getattr(first, name), getattr(other, name)), f"{name}, threads={t}"


def test_concurrent_calls_from_python_threads(big_scene):
    # The GIL is released while rendering: two Python threads rendering at once get the same
    # images as one after the other.
    gaussians, camera = big_scene
    want = api.render(gaussians, camera, threads=2)
    results = [None] * 4

    def work(i):
        results[i] = api.render(gaussians, camera, threads=2)

    workers = [threading.Thread(target=work, args=(i,)) for i in range(len(results))]
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    for got in results:
        _assert_identical(want, got, "concurrent")


def test_big_frames_identical_for_any_thread_count(rng):
    """Big frames and many Gaussians take the parallel prefix sums of the sort and the binning
    (native/src/prefix.c: over 32k counts, e.g. 3,600 tiles x 12 chunks at 1280x720 on 3
    threads, 8,192 digits x 4 chunks for 100k keys on 2): the image is the same bit for bit as
    on one thread, where every pass runs on the calling thread."""
    gaussians = fast_random_gaussians(rng, 100_000, degree=1)
    camera = random_camera(rng, 1280, 720)
    first = api.render(gaussians, camera, threads=1)
    assert first.alpha.mean() > 0.2  # a real workload
    for t in (2, 3, 5):
        _assert_identical(first, api.render(gaussians, camera, threads=t), f"threads={t} vs 1")
