"""The empty balls around the training cameras (`train.free_space`): their radii, which points
they hold (against a float64 brute force on fresh random scenes), and that both strategy
families prune what enters them."""

from __future__ import annotations

import numpy as np

from addon.core.train.config import TrainConfig
from addon.core.train.free_space import CHUNK, FreeSpace
from addon.core.train.optimizer import GaussianParameters
from addon.core.train.strategies import DefaultStrategy, MCMCStrategy
from tests.scenes import random_camera, random_gaussians


def _scene(rng, cameras: int = 12):
    cams = [random_camera(rng, 64, 48, distance=rng.uniform(3.0, 6.0)) for _ in range(cameras)]
    points = rng.normal(scale=1.0, size=(500, 3))
    return cams, points


def test_each_ball_reaches_a_fraction_of_the_way_to_the_nearest_point(rng):
    cams, points = _scene(rng)
    space = FreeSpace.around(cams, points, 0.9)
    for cam, radius in zip(cams, space.radii):
        nearest = np.linalg.norm(points - cam.centre, axis=1).min()
        assert abs(radius - 0.9 * nearest) <= 1e-12 * nearest
    assert FreeSpace.around(cams, points, 0.0) is None
    assert FreeSpace.around(cams, np.empty((0, 3)), 0.9) is None


def _brute_force(space: FreeSpace, means: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inside a ball and out of that camera's view, in float64 one camera at a time; and each
    point's distance to the nearest decision boundary (a sphere, a frustum plane), scaled."""
    means = means.astype(np.float64)
    want = np.zeros(len(means), bool)
    margin = np.full(len(means), np.inf)
    for cam, centre, radius in zip(space.cameras, space.centres, space.radii):
        distance = np.linalg.norm(means - centre, axis=1)
        p = means @ cam.world_to_camera[:3, :3].T + cam.world_to_camera[:3, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            u, v = cam.fx * p[:, 0] / p[:, 2] + cam.cx, cam.fy * p[:, 1] / p[:, 2] + cam.cy
        seen = (p[:, 2] > 0) & (u >= 0) & (u <= cam.width) & (v >= 0) & (v <= cam.height)
        want |= (distance < radius) & ~seen
        edges = np.abs(np.stack([distance - radius, u, u - cam.width, v, v - cam.height], 1))
        margin = np.minimum(margin, np.nan_to_num(edges, nan=np.inf).min(1))
    return want, margin


def test_contains_matches_brute_force(rng):
    cams, points = _scene(rng)
    space = FreeSpace.around(cams, points, 0.9)
    # around the cameras and far out, across more than one block
    near = np.repeat(space.centres, CHUNK // 6, axis=0)
    near = near + rng.normal(size=near.shape) * np.repeat(space.radii, CHUNK // 6)[:, None]
    means = np.concatenate([near, rng.normal(scale=4.0, size=(5000, 3))]).astype(np.float32)
    want, margin = _brute_force(space, means)
    got = space.contains(means)
    assert 0.1 < want.mean() < 0.9
    # the same decisions, but within rounding of a boundary (1e-9 units, 1e-6 pixels)
    clear = margin > 1e-6
    assert clear.mean() > 0.99 and np.array_equal(got[clear], want[clear])
    # no sparse point is ever inside: the balls stop short of the nearest
    assert not space.contains(points).any()


def _params_with_floaters(rng, space: FreeSpace) -> tuple[GaussianParameters, np.ndarray]:
    g = random_gaussians(rng, 400, 0, radius=1.0)
    inside = np.zeros(len(g), bool)
    inside[:40] = True
    which = rng.integers(len(space.centres), size=40)  # behind a camera: out of its view
    behind = -np.array([space.cameras[i].forward for i in which])
    g.means[:40] = (space.centres[which] + 0.5 * space.radii[which, None] * behind
                    + 0.05 * space.radii.min() * rng.uniform(-1, 1, (40, 3)))
    g.opacity_logits[:] = 3.0  # none prunable by opacity
    return GaussianParameters(g), inside


def test_the_reference_densification_prunes_what_enters_the_free_space(rng):
    cams, points = _scene(rng)
    space = FreeSpace.around(cams, points, 0.9)
    params, inside = _params_with_floaters(rng, space)
    config = TrainConfig(strategy="default", densify_grad_threshold=1e9)  # no clones or splits
    strategy = DefaultStrategy(config, 5.0, rng, space)
    strategy.reset(len(params))
    outside = ~space.contains(params.params["means"])
    assert not outside[inside].any()
    kept_means = params.params["means"][outside].copy()
    strategy.densify_and_prune(params, prune_large=False)
    assert np.array_equal(params.params["means"], kept_means)
    without = DefaultStrategy(config, 5.0, rng)  # no free space: nothing pruned
    params, _ = _params_with_floaters(rng, space)
    without.reset(len(params))
    without.densify_and_prune(params, prune_large=False)
    assert len(params) == 400


def test_mcmc_relocates_what_enters_the_free_space(rng):
    cams, points = _scene(rng)
    space = FreeSpace.around(cams, points, 0.9)
    params, inside = _params_with_floaters(rng, space)
    strategy = MCMCStrategy(TrainConfig(strategy="mcmc"), 5.0, rng, space)
    entered = space.contains(params.params["means"])
    assert entered[inside].all()
    assert strategy.relocate(params) == entered.sum()
    assert not space.contains(params.params["means"]).any()
    assert len(params) == 400
