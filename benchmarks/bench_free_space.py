"""Held-out PSNR with and without the cameras' free space (`train.free_space`), until done.

    .venv/bin/python benchmarks/bench_free_space.py examples/demo_colmap --seeds 1
    .venv/bin/python benchmarks/bench_free_space.py ../shared/data/cup --downscale 4

Trains the COLMAP folder with the default recipe until done (compacted, as the product's run
ends) once per fraction and seed, and prints a table: steps, Gaussians, the held-out PSNR and
each held-out view's. A benchmark: it prints, it asserts nothing.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from addon.core.colmap import read_colmap  # noqa: E402
from addon.core.train.dataset import ColmapDataset  # noqa: E402
from addon.core.train.trainer import Trainer, TrainConfig, compact  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("source", type=Path, help="COLMAP folder (sparse/0 + images/)")
    parser.add_argument("--downscale", type=float, default=1.0)
    parser.add_argument("--fractions", type=float, nargs="+", default=[0.0, 0.9])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    cache = Path(tempfile.mkdtemp(prefix="bench-free-space-"))
    scene = read_colmap(args.source, image_folder="images", cache_dir=cache)
    dataset = ColmapDataset(scene, downscale=args.downscale)
    dataset.preload(threads=args.threads)
    names = [dataset.names[i] for i in dataset.test_indices]
    print(f"| fraction | seed | steps | Gaussians | held-out PSNR | {' | '.join(names)} | s |")
    print("|" + " ---: |" * (6 + len(names)))
    for seed in args.seeds:
        for fraction in args.fractions:
            trainer = Trainer(dataset, TrainConfig(steps=0, seed=seed, threads=args.threads,
                                                   free_space_fraction=fraction))
            start = time.perf_counter()
            for _ in trainer.run():
                pass
            compact(trainer)
            views = [trainer.evaluate([i]).psnr for i in dataset.test_indices]
            print(f"| {fraction} | {seed} | {trainer.step} | {len(trainer):,} | "
                  f"{trainer.evaluate().psnr:.2f} | "
                  + " | ".join(f"{v:.2f}" for v in views)
                  + f" | {time.perf_counter() - start:.0f} |", flush=True)


if __name__ == "__main__":
    main()
