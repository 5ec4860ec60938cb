"""Gaussians following a deformation (addon/core/deform): accuracy against analytic fields and
cost at a million Gaussians.

    .venv/bin/python benchmarks/bench_deform.py                 # accuracy, then 1M timings
    .venv/bin/python benchmarks/bench_deform.py --n 200000 --skip-blender
    .venv/bin/python benchmarks/bench_deform.py --skip-accuracy --skip-blender --threads 1

Accuracy: the estimated Jacobian J against the analytic one of a bend (radius 0.5 about Z) and
a twist (2 rad per unit about Z), over points at spacing h in a 0.6-wide block: a jittered 3D
lattice, a uniform random cloud, a sheet (z = 0) and a row (along x); the median and 90th
percentile of |J - J_true| / |J_true| (Frobenius), and the median angle between J's polar
rotation and the true one, for the default thresholds and two others (the variance ratios
below which a direction follows the rotation, above which it is fitted).

Cost (wall clock, best of --repeat, with the CPU seconds of all threads of that run: on a
machine other work loads, the CPU time varies less): the native stages on N Gaussians of SH
degree 3, on --threads (default every core): the rest neighbours, cold, then cached; the fit;
the shapes and SH; the neighbours' spatial layout (with the fit's rest half); the one pass a
frame runs (fit, shapes and SH per Gaussian), into new arrays and, as the gather runs it, over
a fresh copy's own; then in bpy the gather of a splat object of N Gaussians without a modifier
and with a Simple Deform (bend), cache cold (each frame of an animation whose deformation
changes), and cached (a frame whose deformation did not change).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import numpy as np  # noqa: E402

import reference_deform  # noqa: E402
from addon.core import deform  # noqa: E402
from addon.core.deform import DETERMINED, UNDETERMINED  # noqa: E402


def cloud(kind: str, spacing: float, rng) -> np.ndarray:
    axis = np.arange(-0.3, 0.3 + 1e-9, spacing)
    if kind == "lattice":
        p = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
        return p + rng.uniform(-0.2, 0.2, p.shape) * spacing
    if kind == "random":
        return rng.uniform(-0.3, 0.3, (len(axis) ** 3, 3))
    if kind == "sheet":
        p = np.stack(np.meshgrid(axis, axis, indexing="ij"), -1).reshape(-1, 2)
        p = p + rng.uniform(-0.2, 0.2, p.shape) * spacing
        return np.column_stack([p, np.zeros(len(p))])
    return np.column_stack([axis, np.zeros(len(axis)), np.zeros(len(axis))])


def rotation_angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles (degrees) of the rotations a^T b."""
    cos = (np.trace(np.swapaxes(a, 1, 2) @ b, axis1=1, axis2=2) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def accuracy(rng) -> None:
    print("\nAccuracy of J against analytic fields (|J - J_true| / |J_true|: median, p90; "
          "polar rotation: median degrees)\n")
    thresholds = [(UNDETERMINED, DETERMINED), (1e-3, 1e-2), (3e-2, 3e-1)]
    head = " | ".join(f"{lo:g}/{hi:g}" for lo, hi in thresholds)
    print(f"| field | points | spacing | n | {head} |")
    print("| --- | --- | --- | --- |" + " --- |" * len(thresholds))
    for field in ("bend", "twist"):
        for kind in ("lattice", "random", "sheet", "row"):
            if field == "twist" and kind == "row":
                continue  # a twist about the row's own axis leaves a row where it is
            for spacing in (0.08, 0.04, 0.02, 0.01):
                rest = cloud(kind, spacing, rng)
                if field == "twist" and kind == "sheet":
                    rest = rest[:, [0, 2, 1]]  # the sheet along the twist's axis
                moved, truth = (reference_deform.bend(rest, 0.5) if field == "bend"
                                else reference_deform.twist(rest, 2.0))
                truth_rot = np.stack([reference_deform.polar(j) for j in truth])
                rest32, moved32 = rest.astype(np.float32), moved.astype(np.float32)
                nbrs = deform.rest_neighbours(rest32)
                cells = []
                for lo, hi in thresholds:
                    jac, rot = deform.deformation_jacobians(rest32, moved32, nbrs,
                                                            undetermined=lo, determined=hi)
                    err = np.linalg.norm(jac - truth, axis=(1, 2)) / np.linalg.norm(truth,
                                                                                 axis=(1, 2))
                    cells.append(f"{np.median(err):.4f}, {np.percentile(err, 90):.4f}; "
                                 f"{np.median(rotation_angle(rot, truth_rot)):.2f}°")
                print(f"| {field} | {kind} | {spacing} | {len(rest)} | " + " | ".join(cells)
                      + " |")


def timed(function, repeat: int) -> tuple[tuple[float, float], object]:
    """((wall seconds, CPU seconds of every thread), result) of the run with the least wall
    time of `repeat`."""
    best, result = (np.inf, np.inf), None
    for _ in range(repeat):
        start, cpu = time.perf_counter(), time.process_time()
        result = function()
        best = min(best, (time.perf_counter() - start, time.process_time() - cpu))
    return best, result


def cells(seconds: tuple[float, float]) -> str:
    return f"{seconds[0]:.3f} | {seconds[1]:.3f}"


def native_costs(n: int, repeat: int, rng, threads: int) -> None:
    from addon.core.gaussians import Gaussians

    rest = rng.normal(size=(n, 3)).astype(np.float32)
    moved, _ = reference_deform.bend(rest.astype(np.float64), 2.0)
    f = np.float32
    g = Gaussians(moved.astype(f), rng.uniform(-5, -2, (n, 3)).astype(f),
                  rng.normal(size=(n, 4)).astype(f), rng.normal(size=n).astype(f),
                  rng.normal(scale=0.3, size=(n, 16, 3)).astype(f))
    cache = deform.RestNeighbours()
    rows = []
    t, nbrs = timed(lambda: deform.rest_neighbours(rest, threads=threads), 1)
    rows.append(("rest neighbours (k = 8), cold", t))
    cache.get("object", rest)
    t, _ = timed(lambda: cache.get("object", rest), repeat)
    rows.append(("rest neighbours, cached (checksum of the rest positions)", t))
    t, (jac, rot) = timed(lambda: deform.deformation_jacobians(rest, g.means, nbrs,
                                                               threads=threads), repeat)
    rows.append(("fit: J and its polar rotation", t))
    t, _ = timed(lambda: deform.deform_gaussians(g, jac, rot, threads=threads), repeat)
    rows.append(("shapes (J Sigma J^T) and SH degree 3 rotated", t))
    if hasattr(deform, "neighbourhoods"):  # not before the one pass (a baseline's checkout)
        t, hoods = timed(lambda: deform.neighbourhoods(rest, neighbours=nbrs, threads=threads),
                         1)
        rows.append(("spatial layout of the neighbours (once per rest shape, cached)", t))
        t, _ = timed(lambda: deform.deform(g, hoods, threads=threads), repeat)
        rows.append(("one pass: fit, shapes and SH per Gaussian over the spatial rows (a "
                     "frame)", t))
        best = (np.inf, np.inf)
        for _ in range(repeat):  # over a fresh read's arrays, as the gather deforms
            copy = Gaussians(*(a.copy() for a in g.arrays().values()))
            t, _ = timed(lambda: deform.deform(copy, hoods, threads=threads, in_place=True), 1)
            best = min(best, t)
        rows.append(("one pass in place (the gather's)", best))
    print(f"\nNative stages, {n:,} Gaussians, threads {threads or 'all'}\n\n"
          "| stage | seconds | CPU seconds |\n"
          "| --- | --- | --- |")
    for name, seconds in rows:
        print(f"| {name} | {cells(seconds)} |")


def blender_costs(n: int, repeat: int, rng) -> None:
    import bpy

    import bpy_support
    from addon.blender import splat_object
    from addon.blender.sources import gather
    from addon.core.gaussians import Gaussians

    bpy_support.reset_scene()
    f = np.float32
    g = Gaussians(rng.normal(size=(n, 3)).astype(f), rng.uniform(-5, -2, (n, 3)).astype(f),
                  rng.normal(size=(n, 4)).astype(f), rng.normal(size=n).astype(f),
                  rng.normal(scale=0.3, size=(n, 16, 3)).astype(f))
    obj = splat_object.create_splat_object(g, "Splats")
    obj.rotation_euler = (0.3, 0.2, 0.1)  # an object transform: SH rotated in both cases
    bpy.context.view_layer.update()

    def gathered() -> tuple[float, float]:
        depsgraph = bpy.context.evaluated_depsgraph_get()
        cpu = time.process_time()
        seconds = gather.gather(depsgraph).seconds
        return seconds, time.process_time() - cpu

    def cold() -> tuple[float, float]:
        gather.clear_cache()
        return gathered()

    rows = [("no modifier, cache cold (read, transform)", min(cold() for _ in range(repeat)))]
    bend = obj.modifiers.new("Bend", "SIMPLE_DEFORM")
    bend.deform_method, bend.deform_axis, bend.angle = "BEND", "Z", 1.0
    bpy.context.view_layer.update()
    rows.append(("Simple Deform, cache cold, neighbours cold (first frame)", cold()))
    frames = []
    for step in range(repeat):  # a new deformation each frame, neighbours cached
        bend.angle = 1.0 + 0.1 * (step + 1)
        frames.append(gathered())
    rows.append(("Simple Deform, a frame whose deformation changed", min(frames)))
    rows.append(("Simple Deform, a frame whose deformation did not change (cached)",
                 min(gathered() for _ in range(repeat))))
    print(f"\nGather in bpy, {n:,} Gaussians of SH degree 3, object rotated\n\n"
          "| gather | seconds | CPU seconds |\n| --- | --- | --- |")
    for name, seconds in rows:
        print(f"| {name} | {cells(seconds)} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=1_000_000)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--skip-accuracy", action="store_true")
    parser.add_argument("--skip-blender", action="store_true")
    parser.add_argument("--threads", type=int, default=0,
                        help="native stages' threads (0: every core, as the add-on runs them)")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    if not args.skip_accuracy:
        accuracy(rng)
    native_costs(args.n, args.repeat, rng, args.threads)
    if not args.skip_blender:
        blender_costs(args.n, args.repeat, rng)


if __name__ == "__main__":
    main()
