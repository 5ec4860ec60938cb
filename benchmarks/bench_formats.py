"""Every writable splat format: file size and render PSNR after a round trip of the 125k PLAYBOT
scene, and save/load times for synthetic Gaussians (1M, SH degree 3, by default).

    .venv/bin/python benchmarks/bench_formats.py [--count 1000000] [--skip-timing]

PSNR is against the render of the PLY itself (320x240, one fixed camera); sizes are the files
written here. Timing Gaussians are random (positions in a 10 m cube, SH ~ N(0, 0.3)): worse
than real scenes for the k-means of SOG and for compression.
"""

from __future__ import annotations

import argparse
import math
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from addon.core import splat_io  # noqa: E402
from addon.core.cameras import Camera  # noqa: E402
from addon.core.gaussians import Gaussians  # noqa: E402
from addon.core.render.renderer import render  # noqa: E402

PLAYBOT = ROOT.parent / "shared" / "data" / "splats" / "playbot_125k_sh2.ply"
NAMES = ["x.ply", "x.compressed.ply", "x.splat", "x.spz", "x.sog", "meta.json", "x.glb", "x.gltf"]


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b) ** 2))
    return math.inf if mse == 0 else -10 * math.log10(mse)


def size(path: Path) -> int:
    if path.name == "meta.json":
        return sum(p.stat().st_size for p in path.parent.iterdir())
    return path.stat().st_size


def synthetic(n: int, rng: np.random.Generator) -> Gaussians:
    sh = rng.normal(0, 0.3, (n, 16, 3)).astype(np.float32)
    sh[:, 0] = rng.uniform(-1.5, 1.5, (n, 3))
    return Gaussians(rng.uniform(-5, 5, (n, 3)), rng.uniform(-7, -2, (n, 3)), rng.normal(size=(n, 4)),
                     rng.normal(0, 3, n), sh)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=1_000_000)
    parser.add_argument("--skip-timing", action="store_true")
    args = parser.parse_args()
    scene = splat_io.load(PLAYBOT)
    camera = Camera.look_at((0.0, -1.2, -2.6), (0.0, -0.45, 0.0), (0, -1, 0), width=320, height=240,
                            fov_x_degrees=50)
    reference = render(scene, camera).rgb
    big = None if args.skip_timing else synthetic(args.count, np.random.default_rng(0))
    print(f"| format | size, PLAYBOT 125k SH2 | PSNR after round trip | save {args.count} | load {args.count} |")
    print("| --- | --- | --- | --- | --- |")
    for name in NAMES:
        with tempfile.TemporaryDirectory() as folder:
            path = Path(folder) / name
            splat_io.save(scene, path)
            quality = psnr(render(splat_io.load(path), camera).rgb, reference)
            nbytes = size(path)
            times = ["-", "-"]
            if big is not None:
                shutil.rmtree(folder)
                Path(folder).mkdir()
                start = time.perf_counter()
                splat_io.save(big, path)
                middle = time.perf_counter()
                splat_io.load(path)
                end = time.perf_counter()
                times = [f"{middle - start:.2f} s", f"{end - middle:.2f} s"]
        print(f"| {name} | {nbytes / 1e6:.2f} MB | {quality:.1f} dB | {times[0]} | {times[1]} |", flush=True)


if __name__ == "__main__":
    main()
