"""Timings of the Blender side for a big splat object: load into an object, gather, export.

    .venv/bin/python benchmarks/bench_splat_object.py            # 1M Gaussians, SH degree 3
    .venv/bin/python benchmarks/bench_splat_object.py --n 200000 --degree 2

Writes a random standard .ply of N Gaussians to a temporary folder, then times (wall clock, best
of --repeat where it is cheap to repeat):
  - splat_io.load of that file, and bpy.ops.splat.import_splats (file -> splat object);
  - gather (evaluated depsgraph -> world-space Gaussians) uncached at identity, with the cache
    cold (what the first F12 of an object pays), cached, after a rotation + translation +
    uniform scale, after a non-uniform scale;
  - bpy.ops.splat.export_splats to .ply and .spz with the object transformed.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402


def random_gaussians(n: int, degree: int, seed: int = 0):
    from addon.core.gaussians import Gaussians, sh_count

    rng = np.random.default_rng(seed)
    f = np.float32
    means = rng.standard_normal((n, 3), dtype=f) * f(2)
    log_scales = rng.uniform(-5, -2, size=(n, 3)).astype(f)
    quats = rng.standard_normal((n, 4), dtype=f)
    logits = rng.standard_normal(n, dtype=f) * f(2)
    sh = rng.standard_normal((n, sh_count(degree), 3), dtype=f) * f(0.3)
    return Gaussians(means, log_scales, quats, logits, sh)


def timed(function, repeat: int = 1) -> tuple[float, object]:
    best, result = np.inf, None
    for _ in range(repeat):
        start = time.perf_counter()
        result = function()
        best = min(best, time.perf_counter() - start)
    return best, result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=1_000_000)
    parser.add_argument("--degree", type=int, default=3)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()

    import bpy

    import addon
    from addon.blender.sources import gather
    from addon.core import splat_io

    addon.register()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        source = folder / "bench.ply"
        splat_io.save(random_gaussians(args.n, args.degree), source)
        size_mb = source.stat().st_size / 1e6

        seconds, _ = timed(lambda: splat_io.load(source), args.repeat)
        rows.append(("splat_io.load (.ply -> Gaussians)", seconds))

        def import_once():
            for obj in list(bpy.data.objects):
                bpy.data.objects.remove(obj)
            for mesh in list(bpy.data.meshes):
                bpy.data.meshes.remove(mesh)
            bpy.ops.splat.import_splats(filepath=str(source))
        seconds, _ = timed(import_once, args.repeat)
        rows.append(("import_splats (.ply -> splat object)", seconds))
        obj = bpy.context.active_object

        def gather_now(use_cache=True):
            depsgraph = bpy.context.evaluated_depsgraph_get()
            return gather.gather(depsgraph, use_cache=use_cache)

        bpy.context.evaluated_depsgraph_get()
        seconds, result = timed(lambda: gather_now(use_cache=False), args.repeat)
        assert len(result.gaussians) == args.n
        rows.append(("gather, identity transform, uncached", seconds))
        def gather_cold():
            gather.clear_cache()
            return gather_now()
        seconds, result = timed(gather_cold, args.repeat)
        assert result.cache_hits == 0
        rows.append(("gather, cache cold (read, transform, contents checksum)", seconds))
        seconds, result = timed(gather_now, args.repeat)
        assert result.cache_hits == 1
        rows.append(("gather, nothing changed (cached)", seconds))

        obj.location = (1.0, -2.0, 0.5)
        obj.rotation_euler = (0.3, -0.7, 1.1)
        obj.scale = (1.5, 1.5, 1.5)
        bpy.context.evaluated_depsgraph_get()
        seconds, _ = timed(lambda: gather_now(use_cache=False), args.repeat)
        rows.append(("gather, rotated + moved + uniform scale", seconds))
        obj.scale = (1.0, 2.0, 0.5)
        bpy.context.evaluated_depsgraph_get()
        seconds, _ = timed(lambda: gather_now(use_cache=False), 1)
        rows.append(("gather, non-uniform scale (eigen-decomposition)", seconds))
        obj.scale = (1.5, 1.5, 1.5)
        bpy.context.evaluated_depsgraph_get()

        for suffix in (".ply", ".spz"):
            target = folder / f"out{suffix}"
            seconds, _ = timed(lambda: bpy.ops.splat.export_splats(filepath=str(target)), 1)
            rows.append((f"export_splats {suffix} (rotated object, world space)", seconds))

    print(f"{args.n:,} Gaussians, SH degree {args.degree} ({size_mb:.0f} MB .ply)")
    width = max(len(name) for name, _ in rows)
    for name, seconds in rows:
        print(f"  {name:<{width}}  {seconds * 1000:9.1f} ms")


if __name__ == "__main__":
    main()
