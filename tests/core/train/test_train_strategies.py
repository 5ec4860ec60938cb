"""Densification strategies (addon/core/train/strategies) and the parameter store they edit.

The 3DGS-MCMC relocation formula is held against a float64 transcription of the paper's
equation 9 (1e-10 relative), its regulariser gradients against central finite differences of
the regularisers (1e-6 relative); the two-rate SH Adam against Adam on separate DC and rest
arrays (bit for bit). Training runs use the demo COLMAP scene at 120x90."""

from __future__ import annotations

from types import SimpleNamespace

import math
from pathlib import Path

import numpy as np
import pytest

from addon.core.train import kernels
from addon.core.colmap import read_colmap
from addon.core.train.dataset import ColmapDataset
from addon.core.gaussians import Gaussians
from addon.core.train.optimizer import GaussianParameters
from addon.core.train.strategies import STRATEGIES, StepInfo, Strategy, make_strategy
from addon.core.train.strategies.auto import AutoStrategy, LargeImageStrategy
from addon.core.train.strategies.mcmc import MCMCStrategy, relocation
from addon.core.train.config import STRATEGY_NAMES
from addon.core.transform import quat_to_matrix
from addon.core.train.trainer import Trainer, TrainConfig

DEMO = Path(__file__).resolve().parents[3] / "examples" / "demo_colmap"


@pytest.fixture(scope="module")
def dataset() -> ColmapDataset:
    return ColmapDataset(read_colmap(DEMO), downscale=4)


def mcmc_config(**overrides) -> TrainConfig:
    base = dict(strategy="mcmc", steps=120, sh_degree=1, sh_degree_interval=40, densify_from=30,
                densify_every=30, threads=2, seed=3)
    return TrainConfig(**(base | overrides))


def random_gaussians(rng, n: int, degree: int) -> Gaussians:
    return Gaussians(rng.normal(size=(n, 3)), rng.normal(-2, 0.5, (n, 3)), rng.normal(size=(n, 4)),
                     rng.normal(size=n), rng.normal(size=(n, (degree + 1) ** 2, 3)))


def relocation_reference(o: float, s: float, n: int) -> tuple[float, float]:
    """Equation 9 of Kheradmand et al. 2024, term by term in float64."""
    new_o = 1.0 - (1.0 - o) ** (1.0 / n)
    denominator = sum(math.comb(i - 1, k) * (-1) ** k / math.sqrt(k + 1) * new_o ** (k + 1)
                      for i in range(1, n + 1) for k in range(i))
    return new_o, o / denominator * s


def test_relocation_matches_the_paper(rng) -> None:
    o = rng.uniform(0.01, 0.99, 40)
    s = rng.uniform(0.01, 2.0, (40, 3))
    n = rng.integers(1, 30, 40)
    new_o, new_s = relocation(o, s, n)
    for i in range(40):
        want_o, want_s = relocation_reference(o[i], s[i, 0], int(n[i]))
        assert new_o[i] == pytest.approx(want_o, rel=1e-10)
        assert new_s[i, 0] == pytest.approx(want_s, rel=1e-10)
    # n copies of opacity o' cover what the original covered; one copy is the original.
    assert np.allclose(1.0 - (1.0 - new_o) ** n, o, rtol=1e-12)
    same_o, same_s = relocation(o, s, np.ones(40, int))
    assert np.allclose(same_o, o, rtol=1e-14) and np.allclose(same_s, s, rtol=1e-14)


def test_mcmc_regulariser_gradients_match_finite_differences(rng, dataset) -> None:
    config = TrainConfig(strategy="mcmc", mcmc_opacity_reg=0.3, mcmc_scale_reg=0.2)
    g = random_gaussians(rng, 7, 0)
    params = GaussianParameters(g)
    grads = kernels.Gradients.zeros_like(g)
    MCMCStrategy(config, 1.0, rng).after_backward(params, StepInfo(1, None, None, grads, {}))

    def reg(logits, log_scales):
        return (config.mcmc_opacity_reg * np.mean(1 / (1 + np.exp(-logits)))
                + config.mcmc_scale_reg * np.mean(np.exp(log_scales)))

    logits, log_scales = g.opacity_logits.astype(np.float64), g.log_scales.astype(np.float64)
    h = 1e-6
    for i in range(7):
        up, down = logits.copy(), logits.copy()
        up[i] += h
        down[i] -= h
        fd = (reg(up, log_scales) - reg(down, log_scales)) / (2 * h)
        assert grads.opacity_logits[i] == pytest.approx(fd, rel=1e-6)
        up, down = log_scales.copy(), log_scales.copy()
        up[i, 1] += h
        down[i, 1] -= h
        fd = (reg(logits, up) - reg(logits, down)) / (2 * h)
        assert grads.log_scales[i, 1] == pytest.approx(fd, rel=1e-6)


@pytest.mark.parametrize("degree", [0, 2])
def test_sh_adam_with_two_rates_equals_separate_arrays(rng, degree) -> None:
    g = random_gaussians(rng, 33, degree)
    params = GaussianParameters(g)
    dc, rest = [np.ascontiguousarray(g.sh[:, :1]), np.ascontiguousarray(g.sh[:, 1:])]
    moments = [(np.zeros_like(a), np.zeros_like(a)) for a in (dc, rest)]
    lrs = {"means": 1e-3, "log_scales": 1e-3, "quats": 1e-3, "opacity_logits": 1e-3,
           "sh_dc": 2.5e-3, "sh_rest": 1.25e-4}
    for step in range(1, 4):
        grads = kernels.Gradients.zeros_like(g)
        grads.sh[:] = rng.normal(size=grads.sh.shape)
        params.adam_step(grads, lrs, step)
        for array, grad, (m, v), lr in zip((dc, rest), (grads.sh[:, :1], grads.sh[:, 1:]), moments,
                                           (lrs["sh_dc"], lrs["sh_rest"])):
            if array.size:
                kernels.adam_step(array, np.ascontiguousarray(grad), m, v, lr=lr, step=step)
        assert np.array_equal(params.params["sh"], np.concatenate([dc, rest], axis=1))
        assert np.array_equal(params.moments["sh"][1], np.concatenate([moments[0][1], moments[1][1]], axis=1))


def test_mcmc_learns_within_its_budget(dataset) -> None:
    initial = len(Trainer(dataset, mcmc_config()))
    budget = int(initial * 1.08)
    trainer = Trainer(dataset, mcmc_config(max_gaussians=budget))
    start = trainer.evaluate(dataset.train_indices[:6]).psnr
    counts = [len(trainer)]
    for stats in trainer.run():
        assert len(trainer) <= budget
        assert len(trainer) <= int(counts[-1] * 1.05) or len(trainer) == counts[-1]
        counts.append(len(trainer))
    assert counts[-1] == budget  # grew 5 %, then to the budget
    end = trainer.evaluate(dataset.train_indices[:6]).psnr
    assert end > start + 3.0, (start, end)
    assert trainer.gaussians.non_finite() is None


@pytest.mark.parametrize("strategy", ["mcmc", "auto"])
def test_mcmc_is_deterministic_and_resumes_exactly(dataset, tmp_path, strategy) -> None:
    a = Trainer(dataset, mcmc_config(steps=70, strategy=strategy))
    b = Trainer(dataset, mcmc_config(steps=70, threads=1, strategy=strategy))
    list(a.run()), list(b.run())
    first = Trainer(dataset, mcmc_config(steps=70, strategy=strategy))
    list(first.run(35))
    first.save_checkpoint(tmp_path / "state.npz")
    resumed = Trainer.load_checkpoint(tmp_path / "state.npz", dataset)
    assert isinstance(resumed.strategy, STRATEGIES[strategy])
    list(resumed.run())
    for name in a.params:
        assert np.array_equal(a.params[name], b.params[name]), name
        assert np.array_equal(a.params[name], resumed.params[name]), name


def test_mcmc_relocation_moves_dead_gaussians(rng) -> None:
    g = random_gaussians(rng, 50, 1)
    g.opacity_logits[:10] = -10.0  # dead
    params = GaussianParameters(g)
    params.moments["means"][0][:] = 1.0
    strategy = MCMCStrategy(TrainConfig(strategy="mcmc"), 1.0, rng)
    assert strategy.relocate(params) == 10
    assert len(params) == 50
    assert params.opacities().min() > 0.005 - 1e-9
    assert not params.moments["means"][0][:10].any()  # relocated rows start with fresh moments
    assert strategy.grow(params) == 2 and len(params) == 52


def test_mcmc_noise_is_the_gated_covariance_times_a_normal_draw(rng) -> None:
    """R S^2 R^T z x scale x sigmoid(100 (1 - opacity - 0.995)), against float64 matrices, for
    the Gaussians whose gate passes 1e-12 (z: the strategy's draw, one normal triple per row)."""
    g = random_gaussians(rng, 200, 1)
    g.opacity_logits[:] = rng.uniform(-8.0, 3.0, 200)  # some move, some do not
    g.quats[7], g.opacity_logits[7] = 0.0, -8.0  # all zero: the identity; nearly transparent
    params = GaussianParameters(g)
    before = params.params["means"].astype(np.float64)
    opacity = params.opacities()
    gate = 1.0 / (1.0 + np.exp(-100.0 * ((1.0 - opacity) - 0.995)))
    moving = np.flatnonzero(gate > 1e-12)
    assert 20 < len(moving) < 200 and 7 in moving
    strategy = MCMCStrategy(TrainConfig(strategy="mcmc"), 1.0, np.random.default_rng(5))
    strategy.add_noise(params, 3.0)
    z = np.random.default_rng(5).standard_normal((200, 3))[moving]
    r = quat_to_matrix(params.params["quats"][moving])
    variance = np.exp(2.0 * params.params["log_scales"][moving].astype(np.float64))
    sigma = np.einsum("nij,nj,nkj->nik", r, variance, r)
    expected = np.einsum("nij,nj->ni", sigma, z * (3.0 * gate[moving])[:, None])
    moved = params.params["means"].astype(np.float64) - before
    assert not moved[np.setdiff1d(np.arange(200), moving)].any()
    # float32 arithmetic on means of order 1: absolute to their resolution
    assert np.allclose(moved[moving], expected, rtol=1e-4, atol=1e-6)
    assert np.abs(expected).max() > 1e-3  # a test that sees the noise


class Recording(Strategy):
    """Records what the trainer shows a strategy."""

    def reset(self, count: int) -> None:
        self.calls = getattr(self, "calls", []) + [("reset", count)]

    def after_backward(self, params, info) -> None:
        self.calls.append(("after_backward", info.step, bool(info.grads.means.any()),
                           params.params["means"].copy()))

    def after_step(self, params, info) -> int:
        moved = not np.array_equal(self.calls[-1][3], params.params["means"])
        self.calls.append(("after_step", info.step, moved))
        return 0


def test_a_strategy_is_called_around_the_optimizer(dataset) -> None:
    strategy = Recording(TrainConfig(), 1.0, np.random.default_rng(0))
    trainer = Trainer(dataset, TrainConfig(steps=2, threads=2, sh_degree=0), strategy=strategy)
    list(trainer.run())
    kinds = [c[0] for c in strategy.calls]
    assert kinds == ["reset", "after_backward", "after_step", "after_backward", "after_step"]
    assert strategy.calls[1][2]  # gradients are there before Adam
    assert strategy.calls[2][2]  # and Adam ran before after_step


def test_unknown_strategy_is_refused(dataset) -> None:
    assert set(STRATEGY_NAMES) == set(STRATEGIES)  # the names UI lists show are the strategies
    assert {"default", "mcmc", "auto"} <= set(STRATEGIES)
    with pytest.raises(ValueError, match="unknown densification strategy 'nope'.*default"):
        Trainer(dataset, TrainConfig(strategy="nope"))


class _LossStream:
    """Drives an AutoStrategy as a trainer would: steps over 5 views in turn, the loss falling
    smoothly by a given fraction per densification interval (10 steps), then a growth decision."""

    def __init__(self, strategy, params, width: int = 16, height: int = 12) -> None:
        self.strategy, self.params = strategy, params
        self.step, self.loss = 0, 1.0
        self.camera = SimpleNamespace(width=width, height=height)  # all the strategy reads

    def interval(self, fall: float, level: int = 1, steps: int = 10) -> int:
        per_step = (1.0 - fall) ** (1.0 / 10)
        for _ in range(steps):
            self.step += 1
            self.loss *= per_step
            grads = kernels.Gradients.zeros_like(self.params.gaussians)
            self.strategy.after_backward(self.params, StepInfo(
                self.step, self.camera, None, grads, {}, self.loss, level, self.step % 5))
        return self.strategy.grow(self.params)


def test_auto_grows_while_growth_pays_then_settles(rng) -> None:
    config = TrainConfig(strategy="auto", densify_every=10, auto_growth=0.05,
                         auto_gain_per_growth=0.2, auto_patience=2, max_gaussians=10_000)
    params = GaussianParameters(random_gaussians(rng, 200, 0))
    strategy = AutoStrategy(config, 1.0, rng)
    strategy.reset(len(params))
    run = _LossStream(strategy, params)
    # The loss falls 5 % an interval: each 5 % growth bought more than 0.2 x 5 % = 1 %.
    assert all(run.interval(0.05) > 0 for _ in range(4)) and strategy.sizing == "growing"
    # Flat: half of the first flat interval's comparisons reach back into the falling one;
    # then the first miss still grows (patience 2), the second settles the count.
    assert run.interval(0.0) > 0
    assert run.interval(0.0) > 0 and strategy.misses == 1
    assert run.interval(0.0) == 0 and strategy.sizing == "settled"
    count = len(params)
    assert run.interval(0.5) == 0 and run.interval(0.3) == 0  # settled at this resolution
    assert len(params) == count
    # Finer images: it grows again.
    assert run.interval(0.05, level=0) > 0 and strategy.sizing == "growing"
    assert run.interval(-0.1, level=0) > 0  # a rising loss: the first miss
    # An interval cut short (too few views seen twice) gives no verdict.
    assert run.interval(0.0, level=0, steps=1) > 0
    assert run.interval(0.0, level=0) == 0  # the second miss: settled
    # The ceiling holds whatever the loss does.
    strategy.growing = True
    config.max_gaussians = len(params) + 3
    assert run.interval(0.2, level=0) == 3
    assert run.interval(0.2, level=0) == 0 and len(params) == config.max_gaussians


def test_auto_learns_and_keeps_its_sizing_through_a_checkpoint(dataset, tmp_path) -> None:
    trainer = Trainer(dataset, mcmc_config(strategy="auto", steps=150))
    start = trainer.evaluate(dataset.train_indices[:6]).psnr
    history = list(trainer.run())
    assert trainer.evaluate(dataset.train_indices[:6]).psnr > start + 3.0
    assert len(trainer) > history[0]["gaussians"]  # it grew
    assert {s["sizing"] for s in history} <= {"growing", "settled"}
    trainer.save_checkpoint(tmp_path / "state.npz")
    resumed = Trainer.load_checkpoint(tmp_path / "state.npz", dataset)
    for name in ("growing", "misses", "level", "fall_sum", "fall_steps", "previous_count",
                 "view_loss", "pixels"):
        assert getattr(resumed.strategy, name) == getattr(trainer.strategy, name), name


def test_auto_grows_to_a_floor_set_by_the_pixels(rng) -> None:
    # A loss that does not fall at all: on 16x12 images 200 Gaussians are above a quarter of
    # the pixels and the rule settles them; on 160x120 ones they grow by 20 % an interval,
    # whatever the loss, to the floor (4,800), and the rule settles them there.
    counts = {}
    for width, height in ((16, 12), (160, 120)):
        config = TrainConfig(strategy="auto", densify_every=10, auto_growth=0.05,
                             auto_gain_per_growth=1.0, auto_patience=2, max_gaussians=100_000,
                             auto_gaussians_per_pixel=0.25, auto_floor_growth=0.2)
        params = GaussianParameters(random_gaussians(rng, 200, 0))
        strategy = AutoStrategy(config, 1.0, rng)
        strategy.reset(len(params))
        run = _LossStream(strategy, params, width, height)
        grown = [run.interval(0.0) for _ in range(40)]
        counts[width] = len(params)
        assert strategy.sizing == "settled"
        assert strategy.floor() == int(0.25 * width * height)
    assert counts[16] < 250
    assert 4_800 <= counts[160] < 4_800 * 1.2 * 1.05 ** 2  # the floor, then two misses at 5 %
    assert grown[0] == 40  # 20 % of 200 in the first interval, the loss flat
    # 0: no floor, the loss rule alone, as before.
    config.auto_gaussians_per_pixel = 0.0
    assert strategy.floor() == 0


def test_auto_grows_by_its_own_fraction_and_mcmc_by_its(rng) -> None:
    for name, cls in (("auto", AutoStrategy), ("mcmc", MCMCStrategy)):
        config = TrainConfig(strategy=name, auto_growth=0.10, mcmc_growth=0.05)
        params = GaussianParameters(random_gaussians(rng, 1000, 0))
        strategy = cls(config, 1.0, rng)
        strategy.reset(len(params))
        assert strategy.grow(params) == (100 if name == "auto" else 50)


def test_auto_densifies_as_the_reference_on_large_images(dataset) -> None:
    rng = np.random.default_rng(0)
    config = TrainConfig(strategy="auto", auto_reference_above_pixels=100_000)
    assert type(make_strategy(config, 1.0, rng, 100_000)) is AutoStrategy
    assert type(make_strategy(config, 1.0, rng, 480 * 360)) is LargeImageStrategy
    config.auto_reference_above_pixels = 0  # never
    assert type(make_strategy(config, 1.0, rng, 10**7)) is AutoStrategy
    # Step for step the reference recipe (the "default" strategy) once the trainer sees images
    # above the threshold (here 120x90 ones above 5,000 pixels).
    common = dict(steps=60, densify_from=20, densify_every=20, sh_degree=1, threads=1, seed=2)
    auto = Trainer(dataset, TrainConfig(strategy="auto", auto_reference_above_pixels=5_000,
                                        **common))
    reference = Trainer(dataset, TrainConfig(strategy="default", **common))
    assert isinstance(auto.strategy, LargeImageStrategy)
    sizes = [(a["gaussians"], r["gaussians"]) for a, r in zip(auto.run(), reference.run())]
    assert sizes[-1][0] != sizes[0][0] and all(a == r for a, r in sizes)
    for name in auto.params:
        assert np.array_equal(auto.params[name], reference.params[name]), name
    assert auto.strategy.sizing == "growing"
