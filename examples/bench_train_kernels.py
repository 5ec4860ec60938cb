"""Training-kernel benchmark: the backward pass against the forward, and one training step's
kernels (render_train, L1+SSIM loss, backward, Adam over every parameter array).

    .venv/bin/python examples/bench_train_kernels.py           # playbot 1280x720 and 50k at 200x150
    .venv/bin/python examples/bench_train_kernels.py --quick   # the 200x150 case only

Prints median wall-clock ms (and the best run's stages) for 1 and 2 threads, and single-thread
CPU ms, which is steadier on a shared machine. The 50k scene: random Gaussians (SH degree 3)
seen at 200x150, the training size of issue 6. Never a test: numbers only.
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
sys.path.insert(0, str(ROOT / "examples"))
sys.path.insert(0, str(ROOT / "tests"))

from addon.core import render as api  # noqa: E402
from addon.core import splat_io  # noqa: E402
from addon.core import train_kernels as tk  # noqa: E402
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
            _, state = tk.render_train(gaussians, camera, threads=threads)
            grads = tk.backward(state, gaussians, d_rgb, threads=threads)
            render_ms, render_cpu = median_ms(lambda: api.render(gaussians, camera, threads=threads), repeats)
            train_ms, _ = median_ms(lambda: tk.render_train(gaussians, camera, threads=threads), repeats)
            back_ms, back_cpu = median_ms(
                lambda: tk.backward(state, gaussians, d_rgb, threads=threads, out=grads), repeats)
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


def step_table(gaussians, camera, repeats: int) -> None:
    target = np.random.default_rng(1).uniform(0, 1, (camera.height, camera.width, 3)).astype(np.float32)
    moments = {k: (np.zeros_like(a), np.zeros_like(a)) for k, a in gaussians.arrays().items()}
    rows = []
    for threads in (1, 2):
        result, state = tk.render_train(gaussians, camera, threads=threads)
        grads = tk.Gradients.zeros_like(gaussians)
        d_rgb = np.empty_like(target)
        times = {}
        times["render_train"] = median_ms(lambda: tk.render_train(gaussians, camera, threads=threads), repeats)[0]
        times["l1_ssim"] = median_ms(lambda: tk.l1_ssim_loss(result.rgb, target, out_grad=d_rgb,
                                                               threads=threads), repeats)[0]
        times["backward"] = median_ms(lambda: tk.backward(state, gaussians, d_rgb, threads=threads,
                                                          out=grads), repeats)[0]
        params = {k: a.copy() for k, a in gaussians.arrays().items()}

        def adam_all():
            for k, p in params.items():
                tk.adam_step(p, grads.arrays()[k], *moments[k], lr=1e-3, step=1, threads=threads)
        times["adam"] = median_ms(adam_all, repeats)[0]
        rows.append([threads] + [f"{v:.1f}" for v in times.values()] + [f"{sum(times.values()):.1f}"])
    print(f"One training step's kernels, {len(gaussians)} Gaussians (SH degree {gaussians.degree}) "
          f"at {camera.width}x{camera.height} (median wall ms)")
    table(rows, ["threads", "render_train", "l1_ssim", "backward", "adam (all arrays)", "sum"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="the 200x150 case only")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    small = (fast_random_gaussians(rng, 50_000, degree=3), random_camera(rng, 200, 150))
    scenes = {"50k sh3 200x150": small}
    if not args.quick:
        scenes["playbot 1280x720"] = (splat_io.load(str(PLAYBOT)), playbot_camera(1280, 720))
    backward_table(scenes, 5 if args.quick else 7)
    step_table(*small, 9)


if __name__ == "__main__":
    main()
