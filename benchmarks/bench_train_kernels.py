"""Training-kernel benchmark: the backward pass against the forward, and one training step split
into its stages (render_train's project/sort/bin/composite, the L1+SSIM loss, the backward's
composite and per-Gaussian parts, Adam dense and over the visible Gaussians only, and what the
trainer's Python adds around them).

    .venv/bin/python benchmarks/bench_train_kernels.py           # playbot 1280x720 and 50k at 200x150
    .venv/bin/python benchmarks/bench_train_kernels.py --quick   # the 200x150 case only
    .venv/bin/python benchmarks/bench_train_kernels.py --quick --cup 1500   # also cup, trained 1500 steps
    .venv/bin/python benchmarks/bench_train_kernels.py --levels 300   # cup after 300 steps, per
                                                # coarse-to-fine level, one thread (nothing else)

Prints median wall-clock ms (and the best run's stages) for 1 and 2 threads, and single-thread
CPU ms, which is steadier on a shared machine. The 50k scene: random Gaussians (SH degree 3)
seen at 200x150, the training size of issue 6. --cup N: the Gaussians the default trainer has
after N steps on ../shared/data/cup (images_4, 200x150), stepped over its training views, so
visibility and overlap are a real scene's. Never a test: numbers only.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))  # bench_render
sys.path.insert(0, str(ROOT / "tests"))

from addon.core.render import renderer as api  # noqa: E402
from addon.core import splat_io  # noqa: E402
from addon.core.train import kernels  # noqa: E402
from bench_render import PLAYBOT, playbot_camera, table  # noqa: E402
from scenes import fast_random_gaussians, random_camera  # noqa: E402


def median_ms(fn, repeats: int) -> tuple[float, float]:
    """(median wall ms, best CPU ms) over `repeats` calls after a warm-up."""
    fn()
    walls, cpus = [], []
    for _ in range(repeats):
        w, c = time.perf_counter(), time.process_time()
        fn()
        walls.append(1e3 * (time.perf_counter() - w))
        cpus.append(1e3 * (time.process_time() - c))
    return statistics.median(walls), min(cpus)


def backward_table(scenes: dict, repeats: int) -> None:
    rows = []
    for name, (gaussians, camera) in scenes.items():
        d_rgb = np.full((camera.height, camera.width, 3), 0.01, np.float32)
        for threads in (1, 2):
            _, state = kernels.render_train(gaussians, camera, threads=threads)
            grads = kernels.backward(state, gaussians, d_rgb, threads=threads)
            render_ms, render_cpu = median_ms(lambda: api.render(gaussians, camera, threads=threads), repeats)
            train_ms, _ = median_ms(lambda: kernels.render_train(gaussians, camera, threads=threads), repeats)
            back_ms, back_cpu = median_ms(
                lambda: kernels.backward(state, gaussians, d_rgb, threads=threads, out=grads), repeats)
            s = grads.stats
            rows.append([name, threads, f"{render_ms:.1f}", f"{train_ms:.1f}", f"{back_ms:.1f}",
                         f"{s['ms_composite']:.1f}", f"{s['ms_project']:.1f}",
                         f"{back_ms / render_ms:.2f}",
                         f"{back_cpu / render_cpu:.2f}" if threads == 1 else "",
                         f"{state.tile_pairs / 1e3:.0f}k"])
            print("  ".join(map(str, rows[-1])), file=sys.stderr, flush=True)
    print("Backward against forward (median wall ms; backward stages from the last run)")
    table(rows, ["scene", "threads", "render", "render_train", "backward", "bw composite",
                 "bw per-Gaussian", "bw/render", "bw/render CPU", "tile pairs"])


def step_profile(label: str, gaussians, views, repeats: int) -> None:
    """One training step's stages as the trainer runs them (`views`: (camera, target) pairs,
    stepped through in turn). Single-thread CPU ms (best of `repeats` per stage, steadiest
    under load) and 2-thread wall ms (median)."""
    from addon.core.train.optimizer import GaussianParameters

    lrs = {"means": 1e-6, "log_scales": 1e-6, "quats": 1e-6, "opacity_logits": 1e-6,
           "sh_dc": 1e-6, "sh_rest": 1e-6}  # tiny: the Gaussians stay what they were
    rows = []
    for threads, clock in ((1, time.process_time), (2, time.perf_counter)):
        params = GaussianParameters(gaussians)
        g = params.gaussians
        grads = kernels.Gradients.zeros_like(g)
        samples: dict[str, list[float]] = {}
        for r in range(repeats + 1):
            camera, target = views[r % len(views)]
            d_rgb = np.empty_like(target)
            t0 = clock()
            result, state = kernels.render_train(g, camera, threads=threads)
            t1 = clock()
            kernels.l1_ssim_loss(result.rgb, target, out_grad=d_rgb, threads=threads)
            t2 = clock()
            kernels.backward(state, g, d_rgb, threads=threads, out=grads)
            t3 = clock()
            params.adam_step(grads, lrs, r + 1, threads=threads)
            t4 = clock()
            try:
                params.adam_step(grads, lrs, r + 1, rows=state.visible, threads=threads)
                sparse = clock() - t4
            except TypeError:  # an optimizer without visible-rows Adam
                sparse = float("nan")
            if r == 0:
                continue  # warm-up
            stats, bstats = result.stats, grads.stats
            for key, value in (("project", stats["ms_project"]), ("sort", stats["ms_sort"]),
                               ("bin", stats["ms_bin"]), ("composite", stats["ms_composite"]),
                               ("render_train", 1e3 * (t1 - t0)), ("loss", 1e3 * (t2 - t1)),
                               ("bw composite", bstats["ms_composite"]),
                               ("bw per-Gaussian", bstats["ms_project"]),
                               ("backward", 1e3 * (t3 - t2)), ("adam", 1e3 * (t4 - t3)),
                               ("adam visible", 1e3 * sparse), ("step", 1e3 * (t4 - t0)),
                               ("visible %", 100 * state.visible.mean())):
                samples.setdefault(key, []).append(value)
        pick = min if threads == 1 else statistics.median
        rows.append([f"{threads} ({'CPU' if threads == 1 else 'wall'})"] +
                    [f"{(statistics.median if k == 'visible %' else pick)(v):.1f}"
                     for k, v in samples.items()])
        header = list(samples)
    print(f"One training step, {label}: {len(gaussians)} Gaussians (SH degree {gaussians.degree}) "
          f"at {views[0][0].width}x{views[0][0].height}, ms (stages inside render_train and "
          f"backward are the native timers, wall; 'step' = render_train + loss + backward + dense "
          f"Adam)")
    table(rows, ["threads"] + header)


def trained_cup(steps: int):
    """The default trainer's Gaussians after `steps` on cup at 200x150, and its training views."""
    from addon.core.colmap import read_colmap
    from addon.core.train.dataset import ColmapDataset
    from addon.core.train.trainer import Trainer, TrainConfig

    dataset = ColmapDataset(read_colmap(ROOT.parent / "shared" / "data" / "cup",
                                        image_folder="images_4"))
    dataset.preload()
    trainer = Trainer(dataset, TrainConfig(steps=steps, threads=2))
    for _ in trainer.run():
        pass
    views = [(dataset.cameras[i], dataset.image(i)) for i in dataset.train_indices]
    return trainer.gaussians.copy(), views


def level_profile(steps: int, repeats: int) -> None:
    """The default trainer's Gaussians after `steps` on cup (two threads, seed 0), rendered and
    differentiated on one thread at each coarse-to-fine level of one training view (the images
    halved twice, once, not at all), at the degree the trainer renders at that step: each
    stage's native timer (ms), the fastest and the median of `repeats`."""
    from addon.core.colmap import read_colmap
    from addon.core.train.dataset import ColmapDataset
    from addon.core.train.trainer import Trainer, TrainConfig

    dataset = ColmapDataset(read_colmap(ROOT.parent / "shared" / "data" / "cup",
                                        image_folder="images_4"))
    dataset.preload()
    trainer = Trainer(dataset, TrainConfig(steps=0, threads=2, seed=0))
    runs = trainer.run()
    for _ in range(steps):
        next(runs)
    c = trainer.config
    degree = min(c.sh_degree, (trainer.step - 1) // c.sh_degree_interval)
    g = trainer.gaussians.copy()
    rows = []
    for level in (2, 1, 0):
        camera, target = trainer.training_view(dataset.train_indices[3], level)
        result, state = kernels.render_train(g, camera, sh_degree=degree, threads=1,
                                        background=trainer.background)
        d_rgb = kernels.l1_ssim_loss(result.rgb, target, threads=1).grad
        grads = kernels.backward(state, g, d_rgb, threads=1)
        samples: dict[str, list[float]] = {}
        for _ in range(repeats):
            result, state = kernels.render_train(g, camera, sh_degree=degree, threads=1,
                                            background=trainer.background)
            kernels.backward(state, g, d_rgb, threads=1, out=grads)
            s, b = result.stats, grads.stats
            for key, value in (("project", s["ms_project"]), ("sort", s["ms_sort"]),
                               ("bin", s["ms_bin"]), ("composite", s["ms_composite"]),
                               ("render_train", s["ms_total"]), ("bw composite", b["ms_composite"]),
                               ("bw per-Gaussian", b["ms_project"]), ("backward", b["ms_total"])):
                samples.setdefault(key, []).append(value)
        rows.append([f"{camera.width}x{camera.height}", f"{state.tile_pairs}",
                     f"{result.stats['evaluations'] / 1e3:.0f}k"] +
                    [f"{min(v):.2f} / {statistics.median(v):.2f}" for v in samples.values()])
        header = list(samples)
    print(f"cup after {steps} steps: {len(g)} Gaussians, SH degree {degree}, one thread, ms "
          f"(fastest / median of {repeats}; native timers)")
    table(rows, ["size", "tile pairs", "evaluations"] + header)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="the 200x150 case only")
    parser.add_argument("--cup", type=int, default=0, metavar="STEPS",
                        help="also profile cup's Gaussians after this many training steps")
    parser.add_argument("--skip-backward-table", action="store_true")
    parser.add_argument("--levels", type=int, default=0, metavar="STEPS",
                        help="only this: cup after STEPS steps at each coarse-to-fine level")
    args = parser.parse_args()
    if args.levels:
        level_profile(args.levels, 40)
        return
    rng = np.random.default_rng(0)
    small = (fast_random_gaussians(rng, 50_000, degree=3), random_camera(rng, 200, 150))
    scenes = {"50k sh3 200x150": small}
    if not args.quick:
        scenes["playbot 1280x720"] = (splat_io.load(str(PLAYBOT)), playbot_camera(1280, 720))
    if not args.skip_backward_table:
        backward_table(scenes, 5 if args.quick else 7)
    target = np.random.default_rng(1).uniform(0, 1, (150, 200, 3)).astype(np.float32)
    step_profile("random 50k", small[0], [(small[1], target)], 15)
    if args.cup:
        gaussians, views = trained_cup(args.cup)
        step_profile(f"cup after {args.cup} steps", gaussians, views, 30)


if __name__ == "__main__":
    main()
