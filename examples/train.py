"""Train Gaussians from a COLMAP scene on the CPU and write a .ply.

    .venv/bin/python examples/train.py --colmap DIR --images images_4 --steps 7000 \
        --max-gaussians 200000 --out out.ply
    .venv/bin/python examples/train.py --colmap DIR --images images_4 --out out.ply   # until done
    blender --background --python examples/train.py -- --colmap DIR --steps 7000 --out out.ply

With no --steps, training stops when done: when the held-out PSNR gains less than
--stop-gain dB per minute of work over the last minute of work (0.1; checked every 500 steps;
at most 30000 steps; work is a model of each step's cost, so the same run stops at the same
step on a busy machine), keeps its best checked state, then compacts.
The default strategy, "auto", sizes the model itself (--max-gaussians is only a ceiling).
Every 8th image (by name) is held out; held-out PSNR/SSIM is printed every --eval-every steps
and at the end. --compact prunes negligible Gaussians and SH bands afterwards and reports size
against PSNR. --checkpoint saves the full state there at the end (and --resume continues one).
This is the Blender-free trainer with a benchmark's printout; `python -m addon train FOLDER
--out out.ply` (or `blender -c gaussian_splatting train ...`) runs the Train operator instead.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from addon.core import splat_io  # noqa: E402
from addon.core.colmap import read_colmap  # noqa: E402
from addon.core.train.dataset import MAX_WIDTH, ColmapDataset  # noqa: E402
from addon.core.train.trainer import Trainer, TrainConfig, compact, ply_bytes  # noqa: E402
from addon.core.train.config import STRATEGY_NAMES  # noqa: E402

def arguments(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--colmap", required=True, help="COLMAP workspace or model folder")
    parser.add_argument("--images", default="images", help="image folder (images, images_4, ...)")
    parser.add_argument("--downscale", type=float, default=1.0, help="further downscale factor")
    parser.add_argument("--max-width", type=int, default=MAX_WIDTH,
                        help="photos wider than this train at this width (0: full size)")
    parser.add_argument("--steps", type=int, default=None, help="a fixed count (default: until done)")
    parser.add_argument("--stop-gain", type=float, default=TrainConfig.stop_below_db_per_minute,
                        help="without --steps: stop below this held-out gain, dB per minute "
                             "of work")
    parser.add_argument("--strategy", default=TrainConfig.strategy, choices=STRATEGY_NAMES,
                        help="densification: auto (sizes the model itself), mcmc (grows to "
                             "--max-gaussians) or default (the reference's)")
    parser.add_argument("--max-gaussians", type=int, default=TrainConfig.max_gaussians,
                        help="a ceiling on the Gaussian count")
    parser.add_argument("--sh-degree", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=0, help="0: all cores")
    parser.add_argument("--eval-every", type=int, default=500)
    parser.add_argument("--cache-dir", default=None, help="where undistorted photos are cached")
    parser.add_argument("--compact", action="store_true")
    parser.add_argument("--checkpoint", default=None)
    parser.add_argument("--resume", default=None)
    parser.add_argument("--out", required=True, help="the .ply (or .spz/.splat) to write")
    # Under `blender --background --python train.py -- ...` our arguments follow the `--`.
    return parser.parse_args(argv[argv.index("--") + 1:] if "--" in argv else argv[1:])


def main(argv: list[str]) -> None:
    args = arguments(argv)
    start = time.perf_counter()
    scene = read_colmap(args.colmap, image_folder=args.images, cache_dir=args.cache_dir)
    dataset = ColmapDataset(scene, downscale=args.downscale, max_width=args.max_width)
    dataset.preload(threads=args.threads)
    config = TrainConfig(steps=args.steps or 0, max_gaussians=args.max_gaussians,
                         strategy=args.strategy, sh_degree=args.sh_degree, seed=args.seed,
                         threads=args.threads, stop_below_db_per_minute=args.stop_gain)
    trainer = (Trainer.load_checkpoint(args.resume, dataset) if args.resume
               else Trainer(dataset, config))
    trainer.config.steps = config.steps
    steps = trainer.step_limit
    camera = dataset.cameras[0]
    print(f"{len(dataset)} images ({len(dataset.train_indices)} train, "
          f"{len(dataset.test_indices)} held out) at {camera.width}x{camera.height}, "
          f"{len(trainer)} initial Gaussians, loaded in {time.perf_counter() - start:.1f} s")
    print(f"{'step':>6} {'seconds':>8} {'ms/step':>8} {'gaussians':>10} {'MB':>7} "
          f"{'test PSNR':>9} {'test SSIM':>9}")
    train_start, window = time.perf_counter(), []
    for stats in trainer.run():
        window.append(stats["seconds"])
        if stats["step"] % args.eval_every == 0 or stats["step"] == steps:
            ev = trainer.evaluate()
            print(f"{stats['step']:>6} {time.perf_counter() - train_start:>8.1f} "
                  f"{1000 * sum(window) / len(window):>8.1f} {len(trainer):>10} "
                  f"{ply_bytes(len(trainer), trainer.config.sh_degree) / 1e6:>7.2f} "
                  f"{ev.psnr:>9.2f} {ev.ssim:>9.4f} {stats['sizing']}", flush=True)
            window = []
    if trainer.until_done:
        print(f"done at step {trainer.step}: " + (
            f"the held-out PSNR gained less than {args.stop_gain} dB a minute" if trainer.converged
            else f"the most steps ({steps})") + "; compacting")
    if args.compact or trainer.until_done:
        report = compact(trainer)
        print(f"compaction: {report.before} -> {report.after}")
    if args.checkpoint:
        trainer.save_checkpoint(args.checkpoint)
    final = trainer.evaluate()
    splat_io.save(trainer.gaussians, args.out)
    print(f"held-out PSNR {final.psnr:.2f} dB, SSIM {final.ssim:.4f} over {final.views} views; "
          f"{len(trainer)} Gaussians -> {args.out} "
          f"({time.perf_counter() - start:.1f} s in all)")


if __name__ == "__main__":
    main(sys.argv)
