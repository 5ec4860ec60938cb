"""The training loop on the demo COLMAP scene (30 photos, used at 120x90): it learns, it is
deterministic, it resumes exactly, it keeps to its budget, and compaction shrinks it."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from addon.core.train import trainer as train_module
from addon.core.colmap import read_colmap
from addon.core.train.dataset import ColmapDataset
from addon.core.jobs import TrainingJob, status_line
from addon.core.render.renderer import project
from addon.core.train.trainer import (Trainer, TrainConfig, compact, contribution, downscaled_view,
                              initial_gaussians, lr_scale, nearest_mean_sq_distance, position_lr)

DEMO = Path(__file__).resolve().parents[3] / "examples" / "demo_colmap"


@pytest.fixture(scope="module")
def dataset() -> ColmapDataset:
    return ColmapDataset(read_colmap(DEMO), downscale=4)


def short_config(**overrides) -> TrainConfig:
    # The reference strategy, densifying early and often so that a short run exercises clone,
    # split and prune.
    base = dict(strategy="default", steps=120, sh_degree=1, sh_degree_interval=40, densify_from=30,
                densify_every=30, opacity_reset_every=1000, threads=2, seed=3)
    return TrainConfig(**(base | overrides))


def test_nearest_neighbour_distances_match_brute_force(rng) -> None:
    points = rng.normal(size=(300, 3))
    d2 = ((points[:, None] - points[None]) ** 2).sum(-1)
    np.fill_diagonal(d2, np.inf)
    want = np.sort(d2, axis=1)[:, :3].mean(1)
    assert np.allclose(nearest_mean_sq_distance(points, chunk=64), want, rtol=1e-9, atol=1e-12)


def test_initialisation_follows_the_points(rng) -> None:
    xyz, rgb = rng.normal(size=(50, 3)), rng.integers(0, 256, (50, 3)).astype(np.uint8)
    g = initial_gaussians(xyz, rgb, TrainConfig(sh_degree=2), rng)
    assert len(g) == 50 and g.degree == 2
    assert np.allclose(g.means, xyz, atol=1e-6)
    colour = 0.5 + 0.28209479177387814 * g.sh[:, 0]
    assert np.allclose(colour, rgb / 255.0, atol=1e-6)
    assert np.allclose(1 / (1 + np.exp(-g.opacity_logits)), 0.1, atol=1e-6)
    assert np.all(g.sh[:, 1:] == 0)


def test_learning_rate_scale_schedule(dataset) -> None:
    config = TrainConfig(lr_scale_start=4.0, lr_scale_end=0.25, lr_scale_steps=1000)
    assert lr_scale(config, 0) == pytest.approx(4.0)
    assert lr_scale(config, 500) == pytest.approx(1.0)  # exponential: 4 ** 0.5 * 0.25 ** 0.5
    assert lr_scale(config, 250) == pytest.approx(2.0)
    assert lr_scale(config, 1000) == pytest.approx(0.25)
    assert lr_scale(config, 5000) == pytest.approx(0.25)  # then constant
    assert lr_scale(TrainConfig(lr_scale_start=1.0, lr_scale_end=1.0), 700) == 1.0
    plain = Trainer(dataset, short_config(lr_scale_start=1.0, lr_scale_end=1.0))
    scaled = Trainer(dataset, short_config(lr_scale_start=4.0, lr_scale_end=0.25,
                                           lr_scale_steps=1000))
    plain.step = scaled.step = 250
    for name, rate in plain.learning_rates().items():  # every rate, the position rate too
        assert scaled.learning_rates()[name] == pytest.approx(2.0 * rate)


def test_position_learning_rate_schedule() -> None:
    config = TrainConfig()
    assert position_lr(config, 0, 2.0) == pytest.approx(1.6e-4 * 2.0)
    assert position_lr(config, 30_000, 2.0) == pytest.approx(1.6e-6 * 2.0)
    assert position_lr(config, 15_000, 1.0) == pytest.approx(1.6e-5, rel=1e-9)


def test_training_learns_and_densifies(dataset) -> None:
    trainer = Trainer(dataset, short_config())
    start = trainer.evaluate(dataset.train_indices[:6]).psnr
    initial = len(trainer)
    history = list(trainer.run())
    end = trainer.evaluate(dataset.train_indices[:6]).psnr
    assert end > start + 3.0, (start, end)
    assert any(s["densified"] > 0 for s in history)
    assert len(trainer) != initial
    g = trainer.gaussians
    assert g.non_finite() is None
    assert [s["sh_degree"] for s in history][::40] == [0, 1, 1]


def test_training_is_deterministic(dataset) -> None:
    a, b = Trainer(dataset, short_config(steps=60)), Trainer(dataset, short_config(steps=60, threads=1))
    list(a.run()), list(b.run())
    for name in a.params:
        assert np.array_equal(a.params[name], b.params[name]), name


def test_resume_from_checkpoint_equals_a_continuous_run(dataset, tmp_path) -> None:
    whole = Trainer(dataset, short_config(steps=70))
    list(whole.run())
    first = Trainer(dataset, short_config(steps=70))
    list(first.run(35))
    first.save_checkpoint(tmp_path / "state.npz")
    resumed = Trainer.load_checkpoint(tmp_path / "state.npz", dataset)
    list(resumed.run())
    assert resumed.step == 70
    for name in whole.params:
        assert np.array_equal(whole.params[name], resumed.params[name]), name


def test_opacity_reset(dataset) -> None:
    trainer = Trainer(dataset, short_config(steps=20, opacity_reset_every=10))
    list(trainer.run())
    # Reset at step 10 and 20: every opacity is at most 0.01 right after the last one.
    opacity = 1 / (1 + np.exp(-trainer.params["opacity_logits"].astype(np.float64)))
    assert opacity.max() <= 0.01 + 1e-6
    assert not trainer.moments["opacity_logits"][0].any()


def test_budget_is_respected(dataset) -> None:
    initial = len(Trainer(dataset, short_config()))
    budget = initial + 150
    trainer = Trainer(dataset, short_config(max_gaussians=budget, densify_grad_threshold=1e-6))
    for _ in trainer.run():
        assert len(trainer) <= budget


def test_compaction_shrinks_and_reports(dataset) -> None:
    trainer = Trainer(dataset, short_config(steps=80))
    list(trainer.run())
    report = compact(trainer, weight_fraction=0.01, max_psnr_loss_db=0.5, views=4)
    assert report.after["gaussians"] < report.before["gaussians"]
    assert report.after["bytes"] < report.before["bytes"]
    assert report.after["psnr"] > report.before["psnr"] - 1.0
    assert len(trainer) == report.after["gaussians"]


def test_compaction_prunes_no_more_than_the_psnr_allows(dataset) -> None:
    """Half the blending weight is far too much to prune: compaction backs off to a smaller
    fraction within max_psnr_loss_db on the views it measures (the SH step may cost as much
    again); with no limit it prunes that half."""
    trained = Trainer(dataset, short_config(steps=80))
    list(trained.run())
    checkpoint = trained.gaussians
    guarded = compact(trained, weight_fraction=0.5, max_psnr_loss_db=0.05, views=4)
    assert guarded.before["psnr"] - guarded.after["psnr"] <= 2 * 0.05 + 1e-9
    trained.set_gaussians(checkpoint)
    unguarded = compact(trained, weight_fraction=0.5, max_psnr_loss_db=1e9, views=4)
    assert unguarded.after["gaussians"] < guarded.after["gaussians"]
    assert unguarded.before["psnr"] - unguarded.after["psnr"] > 2 * 0.05


def test_stops_when_the_gain_stalls(dataset, tmp_path) -> None:
    # With no step count (0: until done), any real gain is below 1e9 dB a minute: the third
    # check (step 30) stops the run (with no annealing steps after it).
    config = short_config(steps=0, max_steps=120, stop_below_db_per_minute=1e9,
                          stop_window_seconds=0, stop_check_every=10, anneal_steps=0)
    trainer = Trainer(dataset, config)
    history = list(trainer.run())
    assert trainer.converged and trainer.step == 30 and len(history) == 30
    assert len(trainer.checks) == 3
    trainer.save_checkpoint(tmp_path / "state.npz")
    resumed = Trainer.load_checkpoint(tmp_path / "state.npz", dataset)
    assert resumed.converged and resumed.checks == trainer.checks
    assert list(resumed.run()) == []
    # A fixed step count: the count alone ends the run.
    plain = Trainer(dataset, short_config(steps=40, stop_below_db_per_minute=1e9))
    list(plain.run())
    assert plain.step == 40 and not plain.converged and plain.checks == []


def test_coarse_to_fine_schedule_and_views(dataset, rng) -> None:
    trainer = Trainer(dataset, short_config(steps=4000, coarse_levels=2, coarse_until=1000))
    assert [trainer.resolution_level(s) for s in (1, 500, 501, 1000, 1001)] == [2, 2, 1, 1, 0]
    short = Trainer(dataset, short_config(steps=100, coarse_levels=2, coarse_until=1000))
    assert [short.resolution_level(s) for s in (1, 25, 26, 50, 51)] == [2, 2, 1, 1, 0]
    # 120x90 photos halve once at most with the default 32-pixel minimum side.
    assert [trainer.training_view(0, level)[1].shape for level in (0, 1, 2)] == \
        [(90, 120, 3), (45, 60, 3), (45, 60, 3)]
    camera, image = dataset.cameras[0], dataset.image(0)
    small_camera, small = downscaled_view(camera, image, 4)
    h, w = image.shape[0] // 4, image.shape[1] // 4
    assert small.shape == (h, w, 3) and (small_camera.width, small_camera.height) == (w, h)
    want = image[:4 * h, :4 * w].astype(np.float64).reshape(h, 4, w, 4, 3).mean(axis=(1, 3))
    assert np.allclose(small, want, atol=1e-6)
    # A point lands at the same place on the image: pixel coordinates scale by exactly 1/4.
    g = trainer.gaussians.subset(slice(0, 200))
    full, coarse = project(g, camera), project(g, small_camera)
    seen = full.valid & coarse.valid
    assert seen.sum() > 50
    assert np.allclose(coarse.xy[seen], full.xy[seen] / 4, rtol=1e-5, atol=1e-4)


def test_coarse_views_are_kept_while_they_fit(dataset, monkeypatch) -> None:
    """The halved photos of the coarse steps are made once and kept (within a byte bound),
    equal to a fresh `downscaled_view`, and let go once the steps reach full size."""
    trainer = Trainer(dataset, short_config(steps=4000, coarse_levels=2, coarse_until=1000))
    camera, small = trainer.training_view(3, 1)
    assert trainer.training_view(3, 1)[1] is small
    fresh_camera, fresh = downscaled_view(dataset.cameras[3], dataset.image(3), 2)
    assert np.array_equal(small, fresh) and (camera.fx, camera.width) == (fresh_camera.fx, fresh_camera.width)
    assert trainer.coarse_view_bytes == small.nbytes
    trainer.training_view(0, 0)
    assert trainer.coarse_view_bytes == 0
    monkeypatch.setattr(train_module, "COARSE_CACHE_BYTES", small.nbytes)
    trainer.training_view(3, 1)
    again = trainer.training_view(4, 1)[1]  # does not fit: made, used, not kept
    assert trainer.training_view(4, 1)[1] is not again
    assert trainer.coarse_view_bytes == small.nbytes


def test_coarse_to_fine_training_learns(dataset) -> None:
    trainer = Trainer(dataset, short_config(steps=90, coarse_levels=2, coarse_until=45))
    start = trainer.evaluate(dataset.train_indices[:6]).psnr
    history = list(trainer.run())
    assert trainer.evaluate(dataset.train_indices[:6]).psnr > start + 3.0
    assert any(s["densified"] for s in history) and trainer.gaussians.non_finite() is None


def test_a_job_until_done_ends_done_compacts_and_says_so(dataset) -> None:
    config = short_config(steps=0, max_steps=120, stop_below_db_per_minute=1e9,
                          stop_window_seconds=0, stop_check_every=10, strategy="auto",
                          anneal_steps=15)
    seen = []
    job = TrainingJob(Trainer(dataset, config), compact_after=True, on_progress=seen.append).run()
    p = job.progress()  # stalled at step 30, annealed 15 steps
    assert p.phase == "done" and p.step == 45 and p.until_done and p.total == 120
    assert job.compaction is not None and job.final[0] == 45
    training = [x for x in seen if x.phase == "training" and x.step > 20]
    assert training and all(x.sizing in ("growing", "settled") for x in training)
    line = status_line(training[-1])
    assert line.startswith("Training step ") and "(until done)" in line
    assert "Gaussians (growing)" in line or "Gaussians (settled)" in line
    assert "dB/min" in line and "ETA" not in line
    # A fixed count ends at its step and shows its ETA.
    fixed = TrainingJob(Trainer(dataset, short_config(steps=12)), evaluate=False).run()
    assert fixed.progress().phase == "done" and not fixed.progress().until_done
    assert "ETA" in status_line(replace(fixed.progress(), phase="training"))


def test_contribution_counts_dark_gaussians(dataset) -> None:
    # Blending weights do not depend on colour: a black Gaussian (red clamped at 0) covers as
    # much as a grey one and must not read as weightless (compaction would prune it).
    g = Trainer(dataset, short_config()).gaussians.subset(slice(0, 400)).copy()
    cameras = [dataset.cameras[i] for i in dataset.train_indices[:3]]
    grey = contribution(g, cameras, threads=2)
    g.sh[::2] = -5.0  # every other Gaussian black
    dark = contribution(g, cameras, threads=2)
    assert np.array_equal(grey, dark)
    assert (dark[::2] > 0).sum() > 50


def test_a_run_until_done_anneals_its_learning_rates_then_stops(dataset, tmp_path) -> None:
    config = short_config(steps=0, max_steps=120, stop_below_db_per_minute=1e9,
                          stop_window_seconds=0, stop_check_every=10, anneal_steps=20,
                          anneal_to=0.01)
    trainer = Trainer(dataset, config)
    plain = Trainer(dataset, short_config(steps=120))
    rates = {}
    for stats in trainer.run():
        if stats["step"] in (30, 40):
            rates[stats["step"]] = trainer.learning_rates()
            trainer.save_checkpoint(tmp_path / f"at{stats['step']}.npz")
    assert trainer.anneal_from == 30 and trainer.converged and trainer.step == 50
    plain.step = 40
    for name, rate in plain.learning_rates().items():  # half way: 0.01 ** (10 / 20) = 0.1
        assert rates[40][name] == pytest.approx(0.1 * rate, rel=1e-12), name
    resumed = Trainer.load_checkpoint(tmp_path / "at40.npz", dataset)
    assert resumed.anneal_from == 30 and not resumed.converged
    assert len(list(resumed.run())) == 10 and resumed.converged  # it finishes the annealing
    for name in trainer.params:
        assert np.array_equal(trainer.params[name], resumed.params[name]), name
