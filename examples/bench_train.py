"""Training benchmark: held-out PSNR against training seconds and against Gaussian count, per
densification strategy, on ../shared/data/cup (images_4, 200x150) and beer (images_8, 90x160).

    .venv/bin/python examples/bench_train.py [--scenes cup beer] [--strategies default mcmc] \
        [--steps 2000] [--eval-every 250] [--threads 1] [--plot docs/train_curves.png]

Every 8th image (by name) is held out. At every --eval-every steps: training seconds so far
(process CPU time, evaluation excluded), Gaussian count, .ply bytes, held-out PSNR/SSIM (and on cup the PSNR of
1.jpg, the view OpenSplat's CPU trainer is compared on). The curves go to a PNG (matplotlib,
if installed) and their numbers to a JSON beside it. Then (unless --skip-step-times) a
step-time table at fixed Gaussian counts with 1 and 2 threads, split into forward, loss,
backward and Adam. Numbers only, never a test; the machine's load changes the seconds.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from addon.core import train_kernels as tk  # noqa: E402
from addon.core.colmap import read_colmap  # noqa: E402
from addon.core.dataset import ColmapDataset  # noqa: E402
from addon.core.render import render  # noqa: E402
from addon.core.train import Trainer, TrainConfig, ply_bytes, psnr  # noqa: E402

DATA = ROOT.parent / "shared" / "data"
SCENES = {"cup": "images_4", "beer": "images_8"}


def load(scene: str) -> ColmapDataset:
    dataset = ColmapDataset(read_colmap(DATA / scene, image_folder=SCENES[scene]))
    dataset.preload()  # decoding photos is not training time
    return dataset


def curve(dataset: ColmapDataset, scene: str, config: TrainConfig, eval_every: int) -> list[dict]:
    """Train with `config`, evaluating every `eval_every` steps; returns the points."""
    trainer = Trainer(dataset, config)
    probe = dataset.names.index("1.jpg") if "1.jpg" in dataset.names else None
    camera = dataset.cameras[0]
    print(f"\n{scene} at {camera.width}x{camera.height}: "
          f"{len(dataset.train_indices)} train / {len(dataset.test_indices)} held-out views, "
          f"{len(trainer)} initial Gaussians, {config.threads or 'all'} threads")
    print(f"{'step':>6} {'CPU s':>8} {'ms/step':>8} {'gaussians':>9} {'MB':>6} "
          f"{'test PSNR':>9} {'test SSIM':>9} {'1.jpg':>6}")
    # CPU seconds of this process, not wall time: on a shared machine the wall clock mostly
    # measures the other users (with one thread the two agree on an idle machine).
    points, seconds, window = [], 0.0, []
    steps = trainer.run()
    while True:
        before = time.process_time()
        stats = next(steps, None)
        if stats is None:
            break
        spent = time.process_time() - before
        seconds += spent
        window.append(spent)
        if stats["step"] % eval_every == 0 or stats["step"] == config.steps:
            ev = trainer.evaluate()
            one = float("nan")
            if probe is not None:
                rgb = render(trainer.gaussians, dataset.cameras[probe],
                             background=trainer.background, threads=config.threads).rgb
                one = psnr(rgb, dataset.image(probe))
            point = {"step": stats["step"], "cpu_seconds": seconds, "gaussians": len(trainer),
                     "bytes": ply_bytes(len(trainer), config.sh_degree), "psnr": ev.psnr,
                     "ssim": ev.ssim, "probe_psnr": one}
            points.append(point)
            print(f"{stats['step']:>6} {seconds:>8.1f} {1000 * np.mean(window):>8.1f} "
                  f"{len(trainer):>9} {point['bytes'] / 1e6:>6.2f} {ev.psnr:>9.2f} "
                  f"{ev.ssim:>9.4f} {one:>6.2f}", flush=True)
            window = []
    return points


def plot(results: dict, path: Path, note: str) -> None:
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print(f"matplotlib is not installed: no chart ({path} not written)")
        return
    scenes = sorted({scene for scene, _ in results})
    fig, axes = plt.subplots(len(scenes), 2, figsize=(10, 3.6 * len(scenes)), squeeze=False)
    for row, scene in enumerate(scenes):
        for (s, strategy), points in sorted(results.items()):
            if s != scene:
                continue
            psnrs = [p["psnr"] for p in points]
            axes[row, 0].plot([p["cpu_seconds"] for p in points], psnrs, "o-", label=strategy)
            axes[row, 1].plot([p["gaussians"] for p in points], psnrs, "o-", label=strategy)
        axes[row, 0].set(xlabel="training CPU seconds", ylabel="held-out PSNR (dB)", title=scene)
        axes[row, 1].set(xlabel="Gaussians", ylabel="held-out PSNR (dB)", title=scene)
        for ax in axes[row]:
            ax.grid(alpha=0.3)
            ax.legend()
    fig.suptitle(note, fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    print(f"chart: {path}")


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


def parse_variant(text: str) -> tuple[str, dict]:
    """"label:key=value,key=value" -> (label, {key: value}), values typed like TrainConfig's."""
    label, _, pairs = text.partition(":")
    defaults = TrainConfig()
    overrides = {}
    for pair in filter(None, pairs.split(",")):
        key, _, value = pair.partition("=")
        kind = type(getattr(defaults, key))
        overrides[key] = kind(value) if kind is not bool else value.lower() in ("1", "true", "yes")
    return label, overrides


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=list(SCENES), choices=list(SCENES))
    parser.add_argument("--strategies", nargs="+", default=["default", "mcmc"])
    parser.add_argument("--variant", action="append", default=[], metavar="LABEL:KEY=VALUE,...",
                        help="one more curve with TrainConfig overrides, e.g. "
                             "c2f:coarse_levels=2,coarse_until=1000 (repeatable)")
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--eval-every", type=int, default=250)
    parser.add_argument("--max-gaussians", type=int, default=TrainConfig.max_gaussians)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--plot", type=Path, default=ROOT / "docs" / "train_curves.png")
    parser.add_argument("--skip-curve", action="store_true")
    parser.add_argument("--skip-step-times", action="store_true")
    args = parser.parse_args()
    if not args.skip_curve:
        results = {}
        for scene in args.scenes:
            dataset = load(scene)
            runs = [(name, {"strategy": name}) for name in args.strategies]
            runs += [parse_variant(text) for text in args.variant]
            for label, overrides in runs:  # back to back, so the machine's load is alike
                config = TrainConfig(**({"steps": args.steps, "max_gaussians": args.max_gaussians,
                                         "threads": args.threads} | overrides))
                results[scene, label] = curve(dataset, f"{scene} ({label})", config,
                                              args.eval_every)
        note = (f"{args.steps} steps, {args.threads or 'all'} thread(s), every 8th view held out; "
                f"CPU seconds measured on a shared, busy machine ({time.strftime('%Y-%m-%d')})")
        plot(results, args.plot, note)
        args.plot.with_suffix(".json").write_text(json.dumps(
            {f"{scene}/{strategy}": points for (scene, strategy), points in results.items()},
            indent=1))
    if not args.skip_step_times:
        step_times(load("cup"), (10_000, 50_000, 100_000))


if __name__ == "__main__":
    main()
