"""Training benchmark: speed against quality as a curve, on ../shared/data/cup at 200x150.

    .venv/bin/python examples/bench_train.py [--steps 7000] [--max-gaussians 300000]

Every 8th image is held out. Every 500 steps: wall time, mean ms per step over the last 500,
Gaussian count, .ply bytes, PSNR/SSIM on the held-out views, and PSNR on the training view
1.jpg (the number OpenSplat's CPU trainer is compared on). Then a step-time table at fixed
Gaussian counts (10k, 50k, 100k) with 1 and 2 threads, split into forward, loss, backward and
Adam. Numbers only, never a test.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from addon.core import train_kernels as tk  # noqa: E402
from addon.core.colmap import read_colmap  # noqa: E402
from addon.core.dataset import ColmapDataset  # noqa: E402
from addon.core.train import Trainer, TrainConfig, ply_bytes, psnr  # noqa: E402
from addon.core.render import render  # noqa: E402

CUP = ROOT.parent / "shared" / "data" / "cup"


def curve(dataset: ColmapDataset, steps: int, max_gaussians: int, threads: int) -> Trainer:
    trainer = Trainer(dataset, TrainConfig(steps=steps, max_gaussians=max_gaussians,
                                           threads=threads))
    probe = dataset.names.index("1.jpg")
    print(f"cup at {dataset.cameras[0].width}x{dataset.cameras[0].height}: "
          f"{len(dataset.train_indices)} train / {len(dataset.test_indices)} held-out views, "
          f"{len(trainer)} initial Gaussians, {threads or 'all'} threads "
          f"({'1.jpg is a training view' if probe in dataset.train_indices else '1.jpg is held out'})")
    print(f"{'step':>6} {'wall s':>7} {'ms/step':>8} {'gaussians':>9} {'MB':>6} "
          f"{'test PSNR':>9} {'test SSIM':>9} {'1.jpg PSNR':>10}")
    start, window = time.perf_counter(), []
    for stats in trainer.run():
        window.append(stats["seconds"])
        if stats["step"] % 500 == 0 or stats["step"] == steps:
            wall = time.perf_counter() - start
            ev = trainer.evaluate()
            one = render(trainer.gaussians, dataset.cameras[probe], background=trainer.background,
                         threads=threads).rgb
            print(f"{stats['step']:>6} {wall:>7.1f} {1000 * np.mean(window):>8.1f} "
                  f"{len(trainer):>9} {ply_bytes(len(trainer), 3) / 1e6:>6.2f} "
                  f"{ev.psnr:>9.2f} {ev.ssim:>9.4f} {psnr(one, dataset.image(probe)):>10.2f}",
                  flush=True)
            window = []
            start += time.perf_counter() - start - wall  # evaluation time is not training time
    return trainer


def step_times(dataset: ColmapDataset, counts: tuple[int, ...]) -> None:
    print("\nOne training step at fixed Gaussian counts (SH degree 3, median of 20 steps, ms)")
    print(f"{'gaussians':>9} {'threads':>7} {'forward':>8} {'loss':>6} {'backward':>8} "
          f"{'adam':>6} {'total':>6}")
    rng = np.random.default_rng(0)
    base = Trainer(dataset, TrainConfig(max_initial_points=10**9))
    for count in counts:
        pick = rng.choice(len(base), count, replace=count > len(base))
        g = base.gaussians.subset(pick)
        g.means += rng.normal(0, 0.02, g.means.shape).astype(np.float32)
        g.log_scales -= np.float32(np.log(max(count / len(base), 1.0)) / 3)
        for threads in (1, 2):
            times = []
            grads = tk.Gradients.zeros_like(g)
            moments = {k: (np.zeros_like(v), np.zeros_like(v)) for k, v in g.arrays().items()}
            for step in range(20):
                view = dataset.train_indices[step % len(dataset.train_indices)]
                target = dataset.image(view)
                t0 = time.perf_counter()
                result, state = tk.render_train(g, dataset.cameras[view], threads=threads)
                t1 = time.perf_counter()
                loss = tk.l1_ssim_loss(result.rgb, target, threads=threads)
                t2 = time.perf_counter()
                tk.backward(state, g, loss.grad, threads=threads, out=grads)
                t3 = time.perf_counter()
                for name, array in g.arrays().items():
                    m, v = moments[name]
                    tk.adam_step(array, grads.arrays()[name], m, v, lr=1e-9, step=step + 1,
                                 threads=threads)
                t4 = time.perf_counter()
                times.append((t1 - t0, t2 - t1, t3 - t2, t4 - t3, t4 - t0))
            f, l, b, a, t = (1000 * np.median(times, axis=0))
            print(f"{count:>9} {threads:>7} {f:>8.1f} {l:>6.1f} {b:>8.1f} {a:>6.1f} {t:>6.1f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=7000)
    parser.add_argument("--max-gaussians", type=int, default=300_000)
    parser.add_argument("--threads", type=int, default=0)
    parser.add_argument("--skip-curve", action="store_true")
    args = parser.parse_args()
    dataset = ColmapDataset(read_colmap(CUP, image_folder="images_4"))
    dataset.preload()  # decoding photos is not training time
    if not args.skip_curve:
        curve(dataset, args.steps, args.max_gaussians, args.threads)
    step_times(dataset, (10_000, 50_000, 100_000))


if __name__ == "__main__":
    main()
