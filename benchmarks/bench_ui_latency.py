"""How late a 10 ms timer on the main thread runs while training runs on a worker thread (as
the Train operator runs it in Blender): the main thread sleeps 10 ms in a loop and records how
much later than that it woke, the GIL and the cores shared with the training threads.

    .venv/bin/python benchmarks/bench_ui_latency.py [--seconds 30] [--threads 0 1] [--downscale 1]
    blender --background --python benchmarks/bench_ui_latency.py -- --seconds 30

Prints, per kernel thread setting, the lateness's median, 95th percentile and maximum, and the
training steps done meanwhile (the demo scene, 480x360 unless --downscale). `--threads 0` is
what the Train operator runs: every core but one (`jobs.ui_kernel_threads`). Numbers only,
never a test; a loaded machine makes them worse.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from addon.core.colmap import read_colmap  # noqa: E402
from addon.core.jobs import TrainingJob  # noqa: E402
from addon.core.train.dataset import ColmapDataset  # noqa: E402
from addon.core.train.trainer import Trainer, TrainConfig  # noqa: E402


def lateness_while_training(dataset: ColmapDataset, threads: int, seconds: float,
                            period: float = 0.01) -> tuple[np.ndarray, int]:
    job = TrainingJob(Trainer(dataset, TrainConfig(threads=threads, max_steps=10**6)),
                      evaluate=False).start()
    late = []
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        start = time.perf_counter()
        time.sleep(period)
        late.append(time.perf_counter() - start - period)
    job.cancel()
    job.join()
    return np.array(late), job.trainer.step


def main(argv: list[str]) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--threads", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--downscale", type=float, default=1.0)
    args = parser.parse_args(argv[argv.index("--") + 1:] if "--" in argv else argv[1:])
    dataset = ColmapDataset(read_colmap(ROOT / "examples" / "demo_colmap"),
                            downscale=args.downscale)
    dataset.preload()
    camera = dataset.cameras[0]
    print(f"demo scene at {camera.width}x{camera.height}, {args.seconds:.0f} s each; "
          f"switch interval {sys.getswitchinterval() * 1000:.1f} ms")
    print(f"{'threads':>7} {'median ms':>9} {'p95 ms':>7} {'max ms':>7} {'steps':>6}")
    late, _ = lateness_while_training(dataset, 1, 0.0)  # warm up (imports, first allocations)
    for threads in args.threads:
        late, steps = lateness_while_training(dataset, threads, args.seconds)
        ms = 1000 * late
        print(f"{threads:>7} {np.median(ms):>9.2f} {np.percentile(ms, 95):>7.2f} "
              f"{ms.max():>7.1f} {steps:>6}", flush=True)


if __name__ == "__main__":
    main(sys.argv)
