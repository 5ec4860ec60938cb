"""`renderer.seen_by_any`: Gaussians no camera renders can go without changing any render."""

from __future__ import annotations

import numpy as np

from addon.core.gaussians import Gaussians
from addon.core.render.renderer import render, seen_by_any
from scenes import random_camera, random_gaussians


def _concat(a: Gaussians, b: Gaussians) -> Gaussians:
    return Gaussians(*(np.concatenate([getattr(a, n), getattr(b, n)]) for n in (
        "means", "log_scales", "quats", "opacity_logits", "sh")))


def test_far_and_behind_gaussians_are_unseen_and_renders_do_not_change(rng):
    cameras = [random_camera(rng, 48, 36) for _ in range(3)]
    bulk = random_gaussians(rng, 400, 1)
    strays = random_gaussians(rng, 60, 1)
    # Far away (45 km, as after an interrupted training) in directions no camera looks at:
    # 10 km-wide splats well off every camera's view; and tiny ones far off to the side.
    direction = rng.normal(size=(60, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    strays.means[:] = direction * 45_000.0
    strays.log_scales[:] = np.log(10.0)
    scene = _concat(bulk, strays)
    seen = seen_by_any(scene, cameras)
    assert seen[:400].sum() >= 300  # the bulk stays (a few of it may be out of view)
    unseen = np.flatnonzero(~seen)
    assert len(unseen) > 0
    kept = scene.subset(seen)
    for camera in cameras:
        full, pruned = render(scene, camera), render(kept, camera)
        np.testing.assert_allclose(pruned.rgb, full.rgb, atol=2e-6)
        np.testing.assert_allclose(pruned.alpha, full.alpha, atol=2e-6)


def test_a_gaussian_whose_footprint_reaches_into_the_image_is_seen(rng):
    camera = random_camera(rng, 48, 36)
    g = random_gaussians(rng, 200, 0, radius=30.0)  # many around and behind the camera
    seen = seen_by_any(g, [camera])
    assert 0 < seen.sum() < len(g)
    # Each unseen one, rendered alone, leaves the image empty.
    for index in np.flatnonzero(~seen)[:30]:
        alone = render(g.subset(np.arange(len(g)) == index), camera)
        assert alone.alpha.max() == 0.0
