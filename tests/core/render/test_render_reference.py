"""The native renderer (`addon.core.render.renderer`) against the float64 reference (tests/reference.py)
on random scenes with fresh seeds. Tolerances live in tests/checks.py: 1e-4 absolute on rgb and
alpha, 1e-4 relative on depth, ambiguous pixels (< 1%) left out; projection per Gaussian to
~1e-5 relative, scaled by conditioning."""

from __future__ import annotations

import numpy as np
import pytest

from addon.core.render import renderer as api
from tests import reference as ref
from tests.checks import assert_images_match, assert_projection_matches
from tests.scenes import random_mesh_layer, random_scene

# Image sizes that are not multiples of the 16-pixel tile, one picked per test.
SIZES = [(95, 77), (83, 61), (64, 49), (33, 47), (96, 80), (71, 17)]


def _size(rng):
    return SIZES[rng.integers(len(SIZES))]


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
@pytest.mark.parametrize("antialiased", [False, True])
def test_project_matches_reference(rng, degree, antialiased):
    width, height = _size(rng)
    gaussians, camera = random_scene(rng, 1500, width, height, degree)
    got = api.project(gaussians, camera, antialiased=antialiased)
    want = ref.project_scene(gaussians, camera, antialiased=antialiased)
    assert want["valid"].mean() > 0.5 and not want["valid"].all()  # some culled, most kept
    assert_projection_matches(got, want, gaussians.means, *ref.camera_args(camera)[:5])


@pytest.mark.parametrize("sh_degree", [0, 1, 2])
def test_project_truncates_sh_degree(rng, sh_degree):
    gaussians, camera = random_scene(rng, 300, 64, 48, 3)
    got = api.project(gaussians, camera, sh_degree=sh_degree)
    want = ref.project_scene(gaussians, camera, sh_degree=sh_degree)
    assert_projection_matches(got, want, gaussians.means, *ref.camera_args(camera)[:5])


def test_project_custom_near_plane(rng):
    gaussians, camera = random_scene(rng, 1000, 64, 48, 1)
    got = api.project(gaussians, camera, near=5.5)
    want = ref.project_scene(gaussians, camera, near=5.5)
    assert 0.2 < want["valid"].mean() < 0.8  # the near plane cuts through the scene
    assert_projection_matches(got, want, gaussians.means, *ref.camera_args(camera)[:5])


LAYERS = {
    "plain": dict(background=False, mesh=False),
    "background": dict(background=True, mesh=False),
    "mesh": dict(background=False, mesh=True),
    "mesh+background": dict(background=True, mesh=True),
}


@pytest.mark.parametrize("layers", list(LAYERS))
@pytest.mark.parametrize("antialiased", [False, True])
@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_render_matches_reference(rng, degree, antialiased, layers):
    width, height = _size(rng)
    gaussians, camera = random_scene(rng, 400, width, height, degree)
    options = dict(antialiased=antialiased)
    if LAYERS[layers]["background"]:
        options["background"] = rng.random(3).astype(np.float32)
    if LAYERS[layers]["mesh"]:
        options["mesh_rgba"], options["mesh_depth"] = random_mesh_layer(rng, width, height)
    got = api.render(gaussians, camera, **options)
    want = ref.render_scene(gaussians, camera, **options)
    assert 0.05 < want["alpha"].mean()  # something to compare
    assert_images_match(got, want)


def test_render_truncated_sh_and_custom_near(rng):
    width, height = _size(rng)
    gaussians, camera = random_scene(rng, 400, width, height, 3)
    options = dict(sh_degree=1, near=5.0, background=np.float32([0.2, 0.4, 0.6]))
    got = api.render(gaussians, camera, **options)
    want = ref.render_scene(gaussians, camera, **options)
    assert_images_match(got, want)


def test_render_dense_scene_hits_the_transmittance_stop(rng):
    # Opaque, large Gaussians: most pixels stop early, which is where ordering and the stop
    # rule show. The mesh layer sits among them.
    width, height = 48, 40
    gaussians, camera = random_scene(rng, 400, width, height, 1)
    gaussians.opacity_logits[:] = rng.uniform(1, 6, len(gaussians))
    gaussians.log_scales += np.float32(0.7)
    mesh_rgba, mesh_depth = random_mesh_layer(rng, width, height)
    got = api.render(gaussians, camera, mesh_rgba=mesh_rgba, mesh_depth=mesh_depth)
    want = ref.render_scene(gaussians, camera, mesh_rgba=mesh_rgba, mesh_depth=mesh_depth)
    assert (want["alpha"] > 0.999).mean() > 0.3
    assert_images_match(got, want)
