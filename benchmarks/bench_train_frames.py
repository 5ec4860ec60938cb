"""How far apart runs of one training recipe drift: the same photos and settings trained from
the same scene in several frames (the COLMAP frame, the frame the Blender import aligns and
scales it to, a rigid motion, a uniform scale), which differ only in float rounding. Prints the
held-out PSNR and Gaussian count of each at every --eval-every steps. Numbers only, never a test.

    .venv/bin/python benchmarks/bench_train_frames.py [--colmap examples/demo_colmap] [--steps 2000]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from addon.core.colmap import read_colmap  # noqa: E402
from addon.core.train.dataset import ColmapDataset  # noqa: E402
from addon.core.train.trainer import Trainer, TrainConfig  # noqa: E402


def rigid_motion(seed: int = 5) -> np.ndarray:
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    m = np.eye(4)
    m[:3, :3] = q * np.sign(np.linalg.det(q))
    m[:3, 3] = [0.3, -1.2, 0.5]
    return m


def blender_import_dataset(colmap_dir: Path) -> ColmapDataset:
    """The dataset Train Gaussians makes after File > Import > COLMAP Scene (the bpy module)."""
    import bpy
    import bpy_support
    from addon.blender.train.operator import source_of
    bpy_support.ensure_registered()
    bpy_support.reset_scene()
    bpy.ops.splat.import_colmap(directory=str(colmap_dir))
    collection = next(c for c in bpy.data.collections if c.get("colmap_model_dir"))
    return source_of(collection).dataset()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--colmap", type=Path, default=ROOT / "examples" / "demo_colmap")
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--eval-every", type=int, default=500)
    args = parser.parse_args()
    scene = read_colmap(args.colmap)
    frames = {
        "COLMAP": lambda: ColmapDataset(scene),
        "the Blender import": lambda: blender_import_dataset(args.colmap),
        "rotated and moved": lambda: ColmapDataset(scene.transformed(rigid_motion())),
        "scaled x1.89": lambda: ColmapDataset(scene.transformed(np.diag([1.89, 1.89, 1.89, 1.0]))),
    }
    for name, make in frames.items():
        dataset = make()
        dataset.preload()
        trainer = Trainer(dataset, TrainConfig(threads=1))
        row = []
        for _ in trainer.run(args.steps):
            if trainer.step % args.eval_every == 0:
                row.append(f"{trainer.evaluate().psnr:.2f} dB ({len(trainer.gaussians.means):,})")
        print(f"| {name} | " + " | ".join(row) + " |", flush=True)


if __name__ == "__main__":
    main()
