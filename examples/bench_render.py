"""Render benchmark: speed, where the time goes, and speed against error.

    .venv/bin/python examples/bench_render.py            # the full tables (a few minutes)
    .venv/bin/python examples/bench_render.py --quick    # smaller sizes, for a smoke run

Prints, for the real PLAYBOT capture (../shared/data) and synthetic scenes of 10k, 100k and 1M
Gaussians at 640x360, 1280x720 and 1920x1080 with 1 and 2 threads: ms per frame (median of
several), the stages (project, sort, bin, composite), Gaussian/pixel evaluations per second, and
the max error against the float64 reference where the reference is affordable. Then the
compositor's efficiency against its own inner-loop limit (a one-tile, in-cache microbenchmark),
and the knobs that trade speed for fidelity (SH degree, antialiasing). Never a test: numbers only.
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
sys.path.insert(0, str(ROOT / "tests"))

from addon.core import splat_io  # noqa: E402
from addon.core.cameras import Camera  # noqa: E402
from addon.core.gaussians import Gaussians  # noqa: E402
from addon.core.render import render  # noqa: E402

PLAYBOT = ROOT.parent / "shared" / "data" / "splats" / "playbot_125k_sh2.ply"
SIZES = {"640x360": (640, 360), "1280x720": (1280, 720), "1920x1080": (1920, 1080)}


def synthetic(n: int, seed: int = 7) -> Gaussians:
    """`n` Gaussians filling a 2-unit cube, sized so that coverage is similar at every count
    (like a trained scene: more Gaussians, smaller ones), degree 3 SH."""
    rng = np.random.default_rng(seed)
    means = rng.uniform(-1, 1, (n, 3))
    typical = 0.6 * n ** (-1 / 3)
    log_scales = np.log(typical) + rng.normal(0, 0.4, (n, 3))
    quats = rng.normal(size=(n, 4))
    opacity_logits = rng.normal(0, 2, n)
    sh = rng.normal(0, 0.15, (n, 16, 3))
    sh[:, 0] = rng.normal(0, 0.8, (n, 3))
    return Gaussians(means, log_scales, quats, opacity_logits, sh)


def synthetic_camera(width: int, height: int) -> Camera:
    return Camera.look_at((0.4, -3.2, 1.1), (0, 0, 0), (0, 0, 1), width=width, height=height,
                          fov_x_degrees=60)


def playbot_camera(width: int, height: int) -> Camera:
    # The capture stands on y = 0 with -y up; seen from the front, a little above.
    return Camera.look_at((0.0, -0.9, -2.6), (0.0, -0.35, 0.0), (0, -1, 0), width=width,
                          height=height, fov_x_degrees=55)


def timed(gaussians: Gaussians, camera: Camera, repeats: int, **options) -> tuple[float, dict]:
    render(gaussians, camera, **options)  # warm-up: page in, start the pool
    runs = [render(gaussians, camera, **options).stats for _ in range(repeats)]
    best = min(runs, key=lambda s: s["ms_total"])
    return statistics.median(s["ms_total"] for s in runs), best


def reference_error(gaussians: Gaussians, camera: Camera, **options) -> str:
    import reference

    start = time.perf_counter()
    ref = reference.render_scene(gaussians, camera, **options)
    seconds = time.perf_counter() - start
    rgb, alpha, _ = render(gaussians, camera, **options)
    ok = ~ref["ambiguous"]
    err = max(np.abs(rgb - ref["rgb"])[ok].max(), np.abs(alpha - ref["alpha"])[ok].max())
    return f"{err:.1e} ({seconds:.0f} s in float64, {int((~ok).sum())} ambiguous px skipped)"


def table(rows: list[list[str]], header: list[str]) -> None:
    widths = [max(len(str(r[i])) for r in rows + [header]) for i in range(len(header))]
    line = lambda r: "  ".join(str(c).rjust(w) for c, w in zip(r, widths))  # noqa: E731
    print(line(header))
    print("  ".join("-" * w for w in widths))
    for r in rows:
        print(line(r))
    print()


def speed_tables(scenes: dict[str, tuple[Gaussians, callable]], sizes: dict, repeats: int) -> None:
    rows = []
    for name, (gaussians, make_camera) in scenes.items():
        for size_name, (w, h) in sizes.items():
            for threads in (1, 2):
                ms, s = timed(gaussians, make_camera(w, h), repeats, threads=threads)
                rows.append([name, size_name, threads, f"{ms:.1f}", f"{s['ms_project']:.1f}",
                             f"{s['ms_sort']:.1f}", f"{s['ms_bin']:.1f}",
                             f"{s['ms_composite']:.1f}", f"{s['tile_pairs'] / 1e6:.2f}",
                             f"{s['evaluations'] / s['ms_composite'] / 1e3:.0f}"])
                print("  ".join(map(str, rows[-1])), flush=True, file=sys.stderr)
    print("Frame time (median ms) and stages (best run, ms); evals = Gaussian/pixel evaluations")
    table(rows, ["scene", "size", "threads", "ms", "project", "sort", "bin", "composite",
                 "Mpairs", "Meval/s/comp"])


def efficiency(gaussians: Gaussians, camera: Camera) -> None:
    import splatcore

    iterations = 400
    seconds = min(splatcore.composite_microbench(512, iterations) for _ in range(5))
    limit = 512 * 256 * iterations / seconds
    _, s = timed(gaussians, camera, 5, threads=1)
    achieved = s["evaluations"] / (s["ms_composite"] / 1000)
    print("Compositor efficiency (1 thread): inner-loop limit from the one-tile microbenchmark "
          "against the whole composite stage")
    table([[f"{limit / 1e6:.0f}", f"{achieved / 1e6:.0f}", f"{limit / achieved:.2f}"]],
          ["limit Meval/s", "achieved Meval/s", "limit / achieved"])


def knobs(gaussians: Gaussians, camera: Camera, repeats: int) -> None:
    full, _ = timed(gaussians, camera, repeats)
    exact = render(gaussians, camera)
    rows = []
    for degree in range(gaussians.degree, -1, -1):
        ms, _ = timed(gaussians, camera, repeats, sh_degree=degree)
        rgb = render(gaussians, camera, sh_degree=degree).rgb
        err = np.abs(rgb - exact.rgb)
        psnr = 10 * np.log10(1 / max(np.mean(err ** 2), 1e-20))
        rows.append([f"SH degree {degree}", f"{ms:.1f}", f"{err.max():.3f}", f"{psnr:.1f}"])
    ms, _ = timed(gaussians, camera, repeats, antialiased=True)
    rgb = render(gaussians, camera, antialiased=True).rgb
    err = np.abs(rgb - exact.rgb)
    rows.append(["antialiased", f"{ms:.1f}", f"{err.max():.3f}",
                 f"{10 * np.log10(1 / max(np.mean(err ** 2), 1e-20)):.1f}"])
    print(f"Knobs on {len(gaussians)} Gaussians at {camera.width}x{camera.height} "
          f"(against the full render, {full:.1f} ms; the antialiased row is a different look, "
          f"not an error: use the mode the splats were trained in)")
    table(rows, ["setting", "ms", "max abs diff", "PSNR dB"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes only")
    args = parser.parse_args()
    repeats = 3 if args.quick else 7
    sizes = {"640x360": SIZES["640x360"]} if args.quick else SIZES
    counts = (10_000, 100_000) if args.quick else (10_000, 100_000, 1_000_000)

    scenes: dict[str, tuple[Gaussians, callable]] = {}
    if PLAYBOT.exists():
        scenes["playbot 125k"] = (splat_io.load(PLAYBOT), playbot_camera)
    else:
        print(f"({PLAYBOT} not found: real-capture rows skipped)\n")
    for n in counts:
        scenes[f"synthetic {n // 1000}k"] = (synthetic(n), synthetic_camera)
    speed_tables(scenes, sizes, repeats)

    main_scene, main_camera = scenes.get("playbot 125k", scenes["synthetic 100k"])
    efficiency(main_scene, main_camera(1280, 720))
    knobs(main_scene, main_camera(1280, 720), repeats)

    print("Native against the float64 reference (max abs error, rgb and alpha)")
    rows = [["synthetic 10k", "160x90", reference_error(synthetic(10_000), synthetic_camera(160, 90))]]
    if not args.quick:
        rows.append(["synthetic 10k, antialiased", "160x90",
                     reference_error(synthetic(10_000), synthetic_camera(160, 90), antialiased=True)])
        if "playbot 125k" in scenes:
            rows.append(["playbot 125k", "128x72", reference_error(main_scene, main_camera(128, 72))])
    table(rows, ["scene", "size", "max error"])


if __name__ == "__main__":
    main()
