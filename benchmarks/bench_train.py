"""Training benchmark: held-out PSNR against training seconds and against Gaussian count and
bytes, per densification strategy, on ../shared/data/cup (images_4, 200x150), beer (images_8,
88x156 after undistortion) and the embedded demo COLMAP scene (examples/demo_colmap, 120x90),
beside what the 3DGS paper reports at 7K iterations on its benchmark scenes.

    .venv/bin/python benchmarks/bench_train.py [--scenes cup beer demo] \
        [--strategies auto mcmc default] [--steps 2000 | --until-done] [--eval-every 250] \
        [--threads 1] [--cpu-limit SECONDS] [--variant "label:key=value,..."] \
        [--plot docs/train_curves.png]

Every 8th image (by name) is held out. At every --eval-every steps: training seconds so far
(process CPU time, evaluation excluded), Gaussian count, .ply bytes, held-out PSNR/SSIM (and on
cup the PSNR of 1.jpg, the view OpenSplat's CPU trainer is compared on), and the wall seconds
beside (what a user waits; with several threads CPU seconds add the threads' up).
--until-done trains as a user's run with no step count does (until the held-out PSNR gains
less than 0.1 dB a minute), then compacts (the last point; compaction's CPU time included).
With --plot, the curves go to that PNG (matplotlib, if installed): per scene PSNR against CPU seconds and
against Gaussians (MB on the top axis), and a last panel with the end of each run beside the
3DGS paper's 7K and 30K numbers (Kerbl et al. 2023, Table 1: other scenes, at their full
resolution, on a GPU; for scale only). Their numbers go to a JSON beside the PNG. Then (unless --skip-step-times) a
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

from addon.core.train import kernels  # noqa: E402
from addon.core.colmap import read_colmap  # noqa: E402
from addon.core.train.dataset import ColmapDataset  # noqa: E402
from addon.core.render.renderer import render  # noqa: E402
from addon.core.train.trainer import Trainer, TrainConfig, compact, ply_bytes, psnr  # noqa: E402
from addon.core.train.config import STRATEGY_NAMES  # noqa: E402
from addon.core.train import stopping  # noqa: E402

DATA = ROOT.parent / "shared" / "data"
# name: (COLMAP folder, image folder, further downscale)
SCENES = {"cup": (DATA / "cup", "images_4", 1), "beer": (DATA / "beer", "images_8", 1),
          "demo": (ROOT / "examples" / "demo_colmap", "images", 4),
          # The sizes users train at (issue 25): the photos as they are, or halved.
          "demo480": (ROOT / "examples" / "demo_colmap", "images", 1),
          "cup800": (DATA / "cup", "images", 1), "beer360": (DATA / "beer", "images", 2),
          "beer720": (DATA / "beer", "images", 1)}
# --real-sizes: these scenes, the defaults (until done) against the reference recipe (the
# "default" strategy, 7k steps), each cut off at the same CPU seconds.
REAL_SIZES = ("demo480", "cup800", "beer360", "beer720")
REFERENCE_7K = "reference 7k:strategy=default,steps=7000"
# What the 3DGS paper reports (Kerbl et al. 2023, "3D Gaussian Splatting for Real-Time Radiance
# Field Rendering", ACM TOG 42(4), arXiv:2308.04079, Table 1): held-out PSNR (every 8th view),
# training time on one A6000 GPU and the stored model's size, averaged over each benchmark's
# scenes, after 7K and 30K iterations.
LITERATURE_3DGS = [
    # benchmark, iterations, PSNR dB, SSIM, training seconds, MB
    ("Mip-NeRF360", 7_000, 25.60, 0.770, 6 * 60 + 25, 523),
    ("Tanks&Temples", 7_000, 21.20, 0.767, 6 * 60 + 55, 270),
    ("Deep Blending", 7_000, 27.78, 0.875, 4 * 60 + 35, 386),
    ("Mip-NeRF360", 30_000, 27.21, 0.815, 41 * 60 + 33, 734),
    ("Tanks&Temples", 30_000, 23.14, 0.841, 26 * 60 + 54, 411),
    ("Deep Blending", 30_000, 29.41, 0.903, 36 * 60 + 2, 676),
]
LITERATURE_SOURCE = "3DGS paper (Kerbl et al. 2023, Table 1), A6000 GPU, full-size benchmark scenes"


def load(scene: str) -> ColmapDataset:
    folder, images, downscale = SCENES[scene]
    dataset = ColmapDataset(read_colmap(folder, image_folder=images), downscale=downscale)
    dataset.preload()  # decoding photos is not training time
    return dataset


# (CPU seconds, pixels, tile pairs, Gaussians) of every step measured, for --calibrate-work
STEP_COSTS: list[tuple[float, int, int, int]] = []


def fit_work_model() -> None:
    """Least squares of a step's CPU seconds on its pixels, tile pairs and Gaussians (the
    constants of `stopping.step_work`), over the steps of this run's curves."""
    if len(STEP_COSTS) < 10:
        return
    rows = np.array(STEP_COSTS, np.float64)
    features, seconds = rows[:, 1:], rows[:, 0]
    coefficients, *_ = np.linalg.lstsq(features, seconds, rcond=None)
    model = features @ coefficients
    print(f"\nwork model over {len(rows)} steps: seconds = {coefficients[0]:.3g} x pixels + "
          f"{coefficients[1]:.3g} x tile pairs + {coefficients[2]:.3g} x Gaussians; median "
          f"|error| {100 * np.median(np.abs(model / seconds - 1)):.0f} %, total "
          f"{model.sum():.1f} s modelled against {seconds.sum():.1f} s measured")
    current = np.array([stopping.step_work(*f) for f in features.astype(int)])
    print(f"stopping.step_work's constants: total {current.sum():.1f} s against "
          f"{seconds.sum():.1f} s measured")


def _point(trainer: Trainer, probe: int | None, seconds: float, step: int, wall: float,
           **extra) -> dict:
    ev = trainer.evaluate()
    one = float("nan")
    if probe is not None:
        rgb = render(trainer.gaussians, trainer.dataset.cameras[probe],
                     background=trainer.background, threads=trainer.config.threads).rgb
        one = psnr(rgb, trainer.dataset.image(probe))
    degree = trainer.gaussians.degree
    return {"step": step, "cpu_seconds": seconds, "wall_seconds": wall,
            "gaussians": len(trainer), "bytes": ply_bytes(len(trainer), degree),
            "sh_degree": degree, "psnr": ev.psnr,
            "ssim": ev.ssim, "probe_psnr": one} | extra


def curve(dataset: ColmapDataset, scene: str, config: TrainConfig, eval_every: int,
          cpu_limit: float = 0.0) -> list[dict]:
    """Train with `config`, evaluating every `eval_every` steps (and at the end; a run until
    done is compacted then, as a user's is); returns the points. `cpu_limit` > 0: cut the run
    off at the first evaluation past that many CPU seconds (not compacted)."""
    trainer = Trainer(dataset, config)
    probe = dataset.names.index("1.jpg") if "1.jpg" in dataset.names else None
    camera = dataset.cameras[0]
    print(f"\n{scene} at {camera.width}x{camera.height}: "
          f"{len(dataset.train_indices)} train / {len(dataset.test_indices)} held-out views, "
          f"{len(trainer)} initial Gaussians, {config.threads or 'all'} threads, "
          + ("until done" if trainer.until_done else f"{config.steps} steps"))
    print(f"{'step':>6} {'CPU s':>8} {'wall s':>7} {'ms/step':>8} {'gaussians':>9} {'MB':>6} "
          f"{'test PSNR':>9} {'test SSIM':>9} {'1.jpg':>6}")

    def show(point: dict, ms: float, note: str = "") -> None:
        print(f"{point['step']:>6} {point['cpu_seconds']:>8.1f} {point['wall_seconds']:>7.1f} "
              f"{ms:>8.1f} "
              f"{point['gaussians']:>9} {point['bytes'] / 1e6:>6.2f} {point['psnr']:>9.2f} "
              f"{point['ssim']:>9.4f} {point['probe_psnr']:>6.2f}{note}", flush=True)

    # CPU seconds of this process, not wall time: on a shared machine the wall clock mostly
    # measures the other users (with one thread the two agree on an idle machine). The stop
    # test's own evaluations (a run until done) count: they are part of such a run.
    points, seconds, wall, window = [], 0.0, 0.0, []
    steps = trainer.run()
    while True:
        before, wall_before = time.process_time(), time.perf_counter()
        stats = next(steps, None)
        spent = time.process_time() - before
        seconds += spent
        wall += time.perf_counter() - wall_before
        if stats is None:
            break
        window.append(spent)
        if stats["step"] % config.stop_check_every:  # not a step that also ran a stop check
            STEP_COSTS.append((spent, stats["pixels"], stats["tile_pairs"], stats["gaussians"]))
        if stats["step"] % eval_every == 0 or stats["step"] == trainer.step_limit:
            points.append(_point(trainer, probe, seconds, stats["step"], wall,
                                 sizing=stats["sizing"]))
            show(points[-1], 1000 * np.mean(window), f" {stats['sizing']}")
            window = []
            if cpu_limit and seconds >= cpu_limit:
                return points
    if not points or points[-1]["step"] != trainer.step:
        points.append(_point(trainer, probe, seconds, trainer.step, wall))
        show(points[-1], 1000 * np.mean(window or [0.0]))
    if trainer.until_done:
        before, wall_before = time.process_time(), time.perf_counter()
        compact(trainer)
        seconds += time.process_time() - before
        wall += time.perf_counter() - wall_before
        points.append(_point(trainer, probe, seconds, trainer.step, wall, compacted=True))
        why = "converged" if trainer.converged else "at the most steps"
        show(points[-1], 0.0, f" compacted ({why})")
    # The modelled work (`stopping.step_work`, what the stop rule counts: the same on any
    # machine and load) beside the measured seconds.
    print(f"end: step {trainer.step}, {len(trainer)} Gaussians, {seconds:.0f} CPU s, "
          f"{wall:.0f} wall s, work {trainer.work:.0f} modelled s", flush=True)
    return points


def plot(results: dict, path: Path, note: str) -> None:
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print(f"matplotlib is not installed: no chart ({path} not written)")
        return
    scenes = list(dict.fromkeys(scene for scene, _ in results))
    fig, axes = plt.subplots(len(scenes) + 1, 2, figsize=(11, 3.8 * (len(scenes) + 1)),
                             squeeze=False)
    mb_per_gaussian = ply_bytes(1, 3) / 1e6
    for row, scene in enumerate(scenes):
        for (s, strategy), points in results.items():
            if s != scene:
                continue
            psnrs = [p["psnr"] for p in points]
            line, = axes[row, 0].plot([p["cpu_seconds"] for p in points], psnrs, "o-",
                                      ms=3, label=strategy)
            axes[row, 1].plot([p["gaussians"] for p in points], psnrs, "o-", ms=3,
                              color=line.get_color(), label=strategy)
            if points[-1].get("compacted"):
                axes[row, 1].plot(points[-1]["gaussians"], psnrs[-1], "*", ms=10,
                                  color=line.get_color())
        axes[row, 0].set(xlabel="training CPU seconds", ylabel="held-out PSNR (dB)", title=scene)
        axes[row, 1].set(xlabel="Gaussians (star: after compaction)",
                         ylabel="held-out PSNR (dB)", title=scene)
        top = axes[row, 1].secondary_xaxis("top", functions=(lambda n: n * mb_per_gaussian,
                                                             lambda mb: mb / mb_per_gaussian))
        top.set_xlabel(".ply MB at SH degree 3", fontsize=8)
        for ax in axes[row]:
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
    # Where a CPU trainer stands: the end of each run beside the 3DGS paper's numbers.
    ax_time, ax_size = axes[-1]
    for (scene, strategy), points in results.items():
        end = points[-1]
        ax_time.plot(end["cpu_seconds"], end["psnr"], "o")
        ax_time.annotate(f"{scene} {strategy}", (end["cpu_seconds"], end["psnr"]), fontsize=7)
        ax_size.plot(end["bytes"] / 1e6, end["psnr"], "o")
        ax_size.annotate(f"{scene} {strategy}", (end["bytes"] / 1e6, end["psnr"]), fontsize=7)
    for name, iterations, value, _ssim, seconds, mb in LITERATURE_3DGS:
        marker = "s" if iterations == 7_000 else "^"
        label = f"3DGS {iterations // 1000}K: {name}"
        ax_time.plot(seconds, value, marker, color="black", mfc="none")
        ax_time.annotate(label, (seconds, value), fontsize=7)
        ax_size.plot(mb, value, marker, color="black", mfc="none")
        ax_size.annotate(label, (mb, value), fontsize=7)
    ax_time.set(xscale="log", xlabel="training seconds (ours: CPU; 3DGS: A6000 GPU)",
                ylabel="held-out PSNR (dB)", title="end of each run; hollow: " + "3DGS paper")
    ax_size.set(xscale="log", xlabel="model MB (.ply)", ylabel="held-out PSNR (dB)",
                title="different scenes and resolutions: for scale only")
    for ax in axes[-1]:
        ax.grid(alpha=0.3)
    fig.suptitle(note + "\nhollow markers: " + LITERATURE_SOURCE, fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    print(f"chart: {path}")


def save(results: dict, path: Path, note: str) -> None:
    """The curves' numbers, with the literature's, as JSON (what `--replot` reads)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(
        {"note": note, "literature": {"source": LITERATURE_SOURCE, "rows": LITERATURE_3DGS}}
        | {f"{scene}/{label}": points for (scene, label), points in results.items()}, indent=1))


def replot(sources: list[Path], path: Path) -> None:
    """Chart (and save together) the curves of earlier runs' JSON files."""
    results, notes = {}, []
    for source in sources:
        saved = json.loads(source.read_text())
        notes.append(saved.get("note", source.name))
        for key, points in saved.items():
            if "/" in key:
                scene, label = key.split("/", 1)
                results.pop((scene, label), None)
                results[scene, label] = points
    scenes = list(dict.fromkeys(scene for scene, _ in results))  # scene by scene, as measured
    results = {key: results[key] for scene in scenes for key in results if key[0] == scene}
    note = "\n".join(dict.fromkeys(notes))
    plot(results, path, note)
    save(results, path.with_suffix(".json"), note)


def summary(results: dict, marks: list[float]) -> None:
    """A Markdown table: per scene and recipe, the last evaluation at or before each of `marks`
    CPU seconds (what a user has at that time), and the run's last point and best PSNR."""
    print("\n| scene | recipe | CPU s | step | Gaussians | held-out PSNR | SSIM | best so far |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for (scene, label), points in results.items():
        shown = []
        for mark in marks:
            before = [p for p in points if p["cpu_seconds"] <= mark * 1.02]
            if before and before[-1] not in shown:
                shown.append(before[-1])
        if points and points[-1] not in shown:
            shown.append(points[-1])
        for p in shown:
            best = max(q["psnr"] for q in points if q["cpu_seconds"] <= p["cpu_seconds"])
            note = " (compacted)" if p.get("compacted") else ""
            print(f"| {scene} | {label} | {p['cpu_seconds']:.0f} | {p['step']} | "
                  f"{p['gaussians']:,}{note} | {p['psnr']:.2f} | {p['ssim']:.4f} | {best:.2f} |")


def literature_table() -> None:
    print(f"\nFor scale: {LITERATURE_SOURCE} (held-out every 8th view)")
    print(f"{'benchmark':<14} {'iterations':>10} {'PSNR':>6} {'SSIM':>6} {'train':>8} {'MB':>5}")
    for name, iterations, value, ssim, seconds, mb in LITERATURE_3DGS:
        print(f"{name:<14} {iterations:>10,} {value:>6.2f} {ssim:>6.3f} "
              f"{seconds // 60:>4}m{seconds % 60:02d}s {mb:>5}")


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
            grads = kernels.Gradients.zeros_like(g)
            moments = {k: (np.zeros_like(v), np.zeros_like(v)) for k, v in g.arrays().items()}
            for step in range(20):
                view = dataset.train_indices[step % len(dataset.train_indices)]
                target = dataset.image(view)
                t0 = time.perf_counter()
                result, state = kernels.render_train(g, dataset.cameras[view], threads=threads)
                t1 = time.perf_counter()
                loss = kernels.l1_ssim_loss(result.rgb, target, threads=threads)
                t2 = time.perf_counter()
                kernels.backward(state, g, loss.grad, threads=threads, out=grads)
                t3 = time.perf_counter()
                for name, array in g.arrays().items():
                    m, v = moments[name]
                    kernels.adam_step(array, grads.arrays()[name], m, v, lr=1e-9, step=step + 1,
                                 threads=threads)
                t4 = time.perf_counter()
                times.append((t1 - t0, t2 - t1, t3 - t2, t4 - t3, t4 - t0))
            f, loss, b, a, t = (1000 * np.median(times, axis=0))
            print(f"{count:>9} {threads:>7} {f:>8.1f} {loss:>6.1f} {b:>8.1f} {a:>6.1f} {t:>6.1f}")


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
    parser.add_argument("--scenes", nargs="+", default=["cup", "beer", "demo"],
                        choices=list(SCENES))
    parser.add_argument("--strategies", nargs="*", default=list(STRATEGY_NAMES),
                        choices=list(STRATEGY_NAMES))
    parser.add_argument("--variant", action="append", default=[], metavar="LABEL:KEY=VALUE,...",
                        help="one more curve with TrainConfig overrides, e.g. "
                             "c2f:coarse_levels=2,coarse_until=1000 (repeatable)")
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--until-done", action="store_true",
                        help="no step count: train until done, then compact (as a user's run)")
    parser.add_argument("--eval-every", type=int, default=250)
    parser.add_argument("--cpu-limit", type=float, default=0.0, metavar="SECONDS",
                        help="cut each run off at the first evaluation past this many CPU "
                             "seconds (for comparing the start of curves)")
    parser.add_argument("--max-gaussians", type=int, default=TrainConfig.max_gaussians)
    parser.add_argument("--threads", type=int, default=1)
    # No default: a partial run (one scene, a few variants) must not overwrite docs/.
    parser.add_argument("--plot", type=Path, default=None, metavar="PNG",
                        help="write the chart here and the curves' numbers beside it (.json)")
    parser.add_argument("--replot", nargs="+", type=Path, metavar="JSON",
                        help="no training: chart the curves saved in these JSON files (a later "
                             "file's curve replaces an earlier one's of the same name)")
    parser.add_argument("--real-sizes", action="store_true",
                        help="the sizes users train at: " + ", ".join(REAL_SIZES) + ", the "
                             "defaults until done against the reference recipe (7k steps), "
                             "each cut at --cpu-limit (default 240) CPU seconds")
    parser.add_argument("--marks", nargs="*", type=float, default=None, metavar="SECONDS",
                        help="CPU seconds at which the summary table compares the runs")
    parser.add_argument("--skip-curve", action="store_true")
    parser.add_argument("--skip-step-times", action="store_true")
    args = parser.parse_args()
    if args.real_sizes:
        if "--scenes" not in sys.argv:
            args.scenes = list(REAL_SIZES)
        args.strategies, args.until_done = ["auto"], True
        args.variant = [REFERENCE_7K] + args.variant
        args.cpu_limit = args.cpu_limit or 240.0
        args.eval_every = 100 if "--eval-every" not in sys.argv else args.eval_every
        args.skip_step_times = True
    if args.replot:
        replot(args.replot, args.plot or ROOT / "docs" / "train_curves.png")
        return
    if not args.skip_curve:
        results = {}
        steps = 0 if args.until_done else args.steps
        length = ("until done" if args.until_done else f"{args.steps} steps") + (
            " (unless a variant sets steps)" if args.variant else "")
        note = (f"{length}, {args.threads or 'all'} thread(s), every 8th view held out; CPU "
                f"seconds on a shared 2-core machine ({time.strftime('%Y-%m-%d')})")
        for scene in args.scenes:
            dataset = load(scene)
            runs = [(name, {"strategy": name}) for name in args.strategies]
            runs += [parse_variant(text) for text in args.variant]
            for label, overrides in runs:  # back to back, so the machine's load is alike
                config = TrainConfig(**({"steps": steps, "max_gaussians": args.max_gaussians,
                                         "threads": args.threads} | overrides))
                results[scene, label] = curve(dataset, f"{scene} ({label})", config,
                                              args.eval_every, args.cpu_limit)
                if args.plot:
                    save(results, args.plot.with_suffix(".json"), note)  # each run as it ends
        marks = args.marks or ([args.cpu_limit * f for f in (0.25, 0.5, 1.0)]
                               if args.cpu_limit else [])
        summary(results, marks)
        print(f"\n{note}; command: {' '.join(sys.argv)}")
        fit_work_model()
        literature_table()
        if args.plot:
            plot(results, args.plot, note)
    if not args.skip_step_times:
        step_times(load("cup"), (10_000, 50_000, 100_000))


if __name__ == "__main__":
    main()
