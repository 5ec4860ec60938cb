"""Render benchmark: one table of where a frame's time goes, how much work it does and how much
memory it takes, for the real PLAYBOT capture (../shared/data), a synthetic 1M-Gaussian SH3 scene
and the demo scene.

    .venv/bin/python benchmarks/bench_render.py                  # the table (a few minutes)
    .venv/bin/python benchmarks/bench_render.py --quick          # 3 repeats, fewer sizes
    .venv/bin/python benchmarks/bench_render.py --more           # also the compositor's efficiency,
                                                               # the quality knobs and the error
                                                               # against the float64 reference
    .venv/bin/python benchmarks/bench_render.py --no-f12         # without the F12 table (no bpy)
    .venv/bin/python benchmarks/bench_render.py --cameras        # only the camera-type table:
                                                               # pinhole, orthographic and each
                                                               # panorama on PLAYBOT, and their
                                                               # error against float64
    /work/main/.venv/bin/python benchmarks/bench_render.py --code /work/main
                                           # the same table for another checkout's code (before/after)

Columns: ms per frame and per stage (project, sort, bin, composite; medians of the repeats),
Gaussians drawn, Gaussian/tile pairs, Gaussian/pixel evaluations per frame (and, where the code
has the footprint masks, the evaluations without them: the same image's pre-mask work), and
peak memory: the process's resident-set high-water mark during one render above what it held
before (Linux; `VmHWM` reset through /proc/self/clear_refs), which counts the renderer's working
memory and the output images, and the renderer's own count of its working memory at its
largest (stats["peak_bytes"], where the code reports it). Then the F12 table
(benchmarks/bench_render_with_meshes.py): a 1280x720 Cycles frame with and without PLAYBOT's and
the demo scene's splats, the extra split into gather, read, colour, native composite and write,
and the frame's peak memory. Never a test: numbers only.
Wall-clock numbers on a shared machine are noisy: compare runs taken back to back.
"""

from __future__ import annotations

import argparse
import inspect
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
PLAYBOT = ROOT.parent / "shared" / "data" / "splats" / "playbot_125k_sh2.ply"
DEMO = ROOT / "examples" / "demo_scene.ply"


def import_code(code: Path) -> None:
    """Import the add-on's core (and its tests' reference) from the checkout at `code`."""
    sys.path.insert(0, str(code))
    sys.path.insert(0, str(code / "tests"))


def synthetic(n: int, seed: int = 7):
    """`n` Gaussians filling a 2-unit cube, sized so that coverage is similar at every count
    (like a trained scene: more Gaussians, smaller ones), degree 3 SH."""
    from addon.core.gaussians import Gaussians

    rng = np.random.default_rng(seed)
    means = rng.uniform(-1, 1, (n, 3))
    typical = 0.6 * n ** (-1 / 3)
    log_scales = np.log(typical) + rng.normal(0, 0.4, (n, 3))
    quats = rng.normal(size=(n, 4))
    opacity_logits = rng.normal(0, 2, n)
    sh = rng.normal(0, 0.15, (n, 16, 3))
    sh[:, 0] = rng.normal(0, 0.8, (n, 3))
    return Gaussians(means, log_scales, quats, opacity_logits, sh)


def synthetic_camera(width: int, height: int):
    from addon.core.cameras import Camera

    return Camera.look_at((0.4, -3.2, 1.1), (0, 0, 0), (0, 0, 1), width=width, height=height,
                          fov_x_degrees=60)


def playbot_camera(width: int, height: int):
    from addon.core.cameras import Camera

    # The capture stands on y = 0 with -y up; seen from the front, a little above.
    return Camera.look_at((0.0, -0.9, -2.6), (0.0, -0.35, 0.0), (0, -1, 0), width=width,
                          height=height, fov_x_degrees=55)


def demo_camera(width: int, height: int):
    from addon.core.cameras import Camera

    # examples/demo.py's view.
    return Camera.look_at(eye=(5.5, -6.0, 3.2), target=(0.0, 0.0, 0.9), up=(0, 0, 1), width=width,
                          height=height, fov_x_degrees=50)


# ---------------------------------------------------------------- peak memory


def _status_kib(field: str) -> int | None:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(field + ":"):
                return int(line.split()[1])
    except OSError:
        pass
    return None


def peak_mib(run) -> float | None:
    """MiB by which the resident set's high-water mark rose above the resident set during
    `run()`, or None where Linux's /proc interface is not there."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").malloc_trim(0)  # freed heap back to the system: counted again
    except (OSError, AttributeError):
        pass
    try:
        Path("/proc/self/clear_refs").write_text("5")  # reset VmHWM to the current RSS
    except OSError:
        return None
    before = _status_kib("VmRSS")
    run()
    peak = _status_kib("VmHWM")
    return None if before is None or peak is None else (peak - before) / 1024


# ---------------------------------------------------------------- the table


def table(rows: list[list[str]], header: list[str]) -> None:
    widths = [max(len(str(r[i])) for r in rows + [header]) for i in range(len(header))]
    line = lambda r: "  ".join(str(c).rjust(w) for c, w in zip(r, widths))  # noqa: E731
    print(line(header))
    print("  ".join("-" * w for w in widths))
    for r in rows:
        print(line(r))
    print()


def measure(gaussians, camera, repeats: int, threads: int) -> list[str]:
    from addon.core.render.renderer import render

    masks = "exhaustive" in inspect.signature(render).parameters
    render(gaussians, camera, threads=threads)  # warm-up: page in, start the pool
    runs = [render(gaussians, camera, threads=threads).stats for _ in range(repeats)]
    median = lambda key: statistics.median(s[key] for s in runs)  # noqa: E731
    import splatcore

    # Renders keep their working buffers for the next frame (where the code has that): measure
    # the peak of a frame that starts without them.
    getattr(splatcore, "release_buffers", lambda: None)()
    peak = peak_mib(lambda: render(gaussians, camera, threads=threads))
    unmasked = "-"
    if masks:
        unmasked = f"{render(gaussians, camera, threads=threads, exhaustive=True).stats['evaluations'] / 1e6:.1f}"
    s = runs[0]
    return [f"{median('ms_total'):.1f}", f"{median('ms_project'):.1f}", f"{median('ms_sort'):.1f}",
            f"{median('ms_bin'):.1f}", f"{median('ms_composite'):.1f}", f"{s['visible'] / 1e3:.0f}k",
            f"{s['tile_pairs'] / 1e6:.2f}", f"{s['evaluations'] / 1e6:.1f}", unmasked,
            "-" if peak is None else f"{peak:.0f}",
            f"{s['peak_bytes'] / 2**20:.0f}" if "peak_bytes" in s else "-"]


def scenes(quick: bool) -> list[tuple[str, callable, callable, list[tuple[int, int]]]]:
    """(name, load, camera, sizes) per scene; loads lazily so that one scene is held at a time."""
    from addon.core import splat_io

    out = []
    if PLAYBOT.exists():
        sizes = [(800, 600), (1920, 1080)] if quick else [(800, 600), (1280, 720), (1920, 1080)]
        out.append(("playbot 125k SH2", lambda: splat_io.load(PLAYBOT), playbot_camera, sizes))
    else:
        print(f"({PLAYBOT} not found: the real-capture rows are skipped)\n")
    sizes = [(1280, 720)] if quick else [(1280, 720), (1920, 1080)]
    out.append(("synthetic 1M SH3", lambda: synthetic(1_000_000), synthetic_camera, sizes))
    out.append(("demo scene", lambda: splat_io.load(DEMO), demo_camera, [(960, 540), (1920, 1080)]))
    return out


def main_table(args) -> None:
    rows = []
    for name, load, make_camera, sizes in scenes(args.quick):
        gaussians = load()
        for width, height in sizes:
            row = [name if not rows or rows[-1][0] != name else "", f"{width}x{height}",
                   *measure(gaussians, make_camera(width, height), args.repeats, args.threads)]
            rows.append(row)
            print("  ".join(row), file=sys.stderr, flush=True)
        del gaussians
    print(f"Render stages ({args.threads} threads, median of {args.repeats}; code: {args.code}); "
          "evaluations = Gaussian/pixel evaluations per frame, 'no masks' = the same frame "
          "evaluated over each tile's whole bounding span; peak = resident-set high-water mark "
          "above the resident set before the render (working buffers released first; images "
          "included); working = the renderer's own count of its largest working memory")
    table(rows, ["scene", "size", "ms", "project", "sort", "bin", "composite", "drawn", "Mpairs",
                 "Meval", "no masks", "peak MiB", "working MiB"])


# ---------------------------------------------------------------- --cameras


def camera_types(make_camera, width: int, height: int) -> list[tuple[str, object]]:
    """The pinhole view `make_camera(width, height)` and, from the same pose, an orthographic
    view of the same width at the target (the pinhole's field at its target distance), and each
    panorama (equirectangular and central cylindrical at 2:1, the fisheyes, the mirror ball and
    the cubemap face square)."""
    import dataclasses
    import math

    from addon.core.cameras import Camera

    pinhole = make_camera(width, height)
    distance = 2.7  # about the target distance of the scenes' cameras
    ortho = dataclasses.replace(pinhole, model="ORTHO", fx=pinhole.fx / distance,
                                fy=pinhole.fy / distance)
    side = height
    dof = dataclasses.replace(pinhole, aperture=0.05 / (2 * 1.4), focus=distance)  # 50 mm f/1.4
    out = [("pinhole", pinhole), ("pinhole, depth of field", dof), ("orthographic", ortho)]
    pose = pinhole.world_to_camera
    full = (-math.pi, math.pi, -math.pi / 2, math.pi / 2)
    for name, model, params, w, h in [
            ("equirectangular", "EQUIRECTANGULAR", full, 2 * round(side * 1024 / 1080),
             round(side * 1024 / 1080)),
            ("fisheye equidistant 180", "FISHEYE_EQUIDISTANT", (math.pi,), side, side),
            ("fisheye equisolid 10.5mm", "FISHEYE_EQUISOLID", (10.5, math.pi, 36.0, 36.0), side,
             side),
            ("mirror ball", "MIRRORBALL", (), side, side),
            ("fisheye lens polynomial", "FISHEYE_LENS_POLYNOMIAL",
             (-1.1735e-05, -0.019989, -3.3525e-06, 3.0993e-06, -2.6065e-08, math.pi, 36.0, 36.0),
             side, side),
            ("equiangular cubemap face", "EQUIANGULAR_CUBEMAP_FACE", (), side, side),
            ("central cylindrical", "CENTRAL_CYLINDRICAL", (-math.pi, math.pi, -1.0, 1.0),
             2 * round(side * 1024 / 1080), round(side * 1024 / 1080))]:
        out.append((name, Camera(pose, w, h, 0.0, h, w, h, model=model, params=params)))
    return out


def camera_table(args) -> None:
    """Per camera type: the frame's stages on PLAYBOT (or a synthetic scene), and the error
    against the float64 reference on a small synthetic frame of the same camera type."""
    from addon.core import splat_io

    if PLAYBOT.exists():
        name, gaussians, make_camera = "playbot 125k SH2", splat_io.load(PLAYBOT), playbot_camera
    else:
        name, gaussians, make_camera = "synthetic 1M SH3", synthetic(1_000_000), synthetic_camera
    rows = []
    for label, camera in camera_types(make_camera, 1920, 1080):
        row = [label, f"{camera.width}x{camera.height}",
               *measure(gaussians, camera, args.repeats, args.threads)[:8]]
        rows.append(row)
        print("  ".join(row), file=sys.stderr, flush=True)
    print(f"Camera types on {name} ({args.threads} threads, median of {args.repeats}); the "
          "pinhole and orthographic views are 1920x1080 from the same pose, the equirectangular "
          "2048x1024 from that pose, the others 1080x1080")
    table(rows, ["camera", "size", "ms", "project", "sort", "bin", "composite", "drawn",
                 "Mpairs", "Meval"])
    small = synthetic(10_000)
    rows = []
    for label, camera in camera_types(synthetic_camera, 160, 90):
        near = -10.0 if camera.model == "ORTHO" else 0.01
        rows.append([label, f"{camera.width}x{camera.height}",
                     reference_error(small, camera, near=near)])
        print("  ".join(rows[-1]), file=sys.stderr, flush=True)
    print("Native against the float64 reference per camera type (synthetic 10k SH3; max abs "
          "error of rgb and alpha)")
    table(rows, ["camera", "size", "max error"])


# ---------------------------------------------------------------- --more


def efficiency(gaussians, camera) -> None:
    import splatcore
    from addon.core.render.renderer import render

    iterations = 400
    seconds = min(splatcore.composite_microbench(512, iterations) for _ in range(5))
    limit = 512 * 256 * iterations / seconds
    stats = min((render(gaussians, camera, threads=1).stats for _ in range(5)),
                key=lambda s: s["ms_composite"])
    achieved = stats["evaluations"] / (stats["ms_composite"] / 1000)
    print("Compositor efficiency (1 thread): inner-loop limit from the one-tile microbenchmark "
          "against the whole composite stage")
    table([[f"{limit / 1e6:.0f}", f"{achieved / 1e6:.0f}", f"{limit / achieved:.2f}"]],
          ["limit Meval/s", "achieved Meval/s", "limit / achieved"])


def knobs(gaussians, camera, repeats: int) -> None:
    from addon.core.render.renderer import render

    def timed(**options) -> float:
        render(gaussians, camera, **options)
        return statistics.median(render(gaussians, camera, **options).stats["ms_total"]
                                 for _ in range(repeats))

    exact = render(gaussians, camera)
    rows = []
    for label, options in [*((f"SH degree {d}", dict(sh_degree=d))
                             for d in range(gaussians.degree, -1, -1)),
                           ("antialiased", dict(antialiased=True))]:
        err = np.abs(render(gaussians, camera, **options).rgb - exact.rgb)
        psnr = 10 * np.log10(1 / max(np.mean(err ** 2), 1e-20))
        rows.append([label, f"{timed(**options):.1f}", f"{err.max():.3f}", f"{psnr:.1f}"])
    print(f"Knobs on {len(gaussians)} Gaussians at {camera.width}x{camera.height} (against the full "
          f"render; the antialiased row is a different look, not an error: use the mode the "
          f"splats were trained in)")
    table(rows, ["setting", "ms", "max abs diff", "PSNR dB"])


def reference_error(gaussians, camera, **options) -> str:
    import reference
    from addon.core.render.renderer import render

    start = time.perf_counter()
    ref = reference.render_scene(gaussians, camera, **options)
    seconds = time.perf_counter() - start
    rgb, alpha, _ = render(gaussians, camera, **options)
    ok = ~ref["ambiguous"]
    err = max(np.abs(rgb - ref["rgb"])[ok].max(), np.abs(alpha - ref["alpha"])[ok].max())
    return f"{err:.1e} ({seconds:.0f} s in float64, {int((~ok).sum())} ambiguous px skipped)"


def more_tables(args) -> None:
    from addon.core import splat_io

    if PLAYBOT.exists():
        gaussians, make_camera = splat_io.load(PLAYBOT), playbot_camera
    else:
        gaussians, make_camera = synthetic(100_000), synthetic_camera
    efficiency(gaussians, make_camera(1280, 720))
    knobs(gaussians, make_camera(1280, 720), args.repeats)
    print("Native against the float64 reference (max abs error, rgb and alpha)")
    rows = [["synthetic 10k", "160x90", reference_error(synthetic(10_000), synthetic_camera(160, 90))],
            ["synthetic 10k, antialiased", "160x90",
             reference_error(synthetic(10_000), synthetic_camera(160, 90), antialiased=True)],
            ["demo scene", "192x108", reference_error(splat_io.load(DEMO), demo_camera(192, 108))]]
    table(rows, ["scene", "size", "max error"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="3 repeats and fewer sizes")
    parser.add_argument("--more", action="store_true",
                        help="also efficiency, quality knobs and the error against float64")
    parser.add_argument("--threads", type=int, default=2, help="worker threads (default 2)")
    parser.add_argument("--repeats", type=int, default=None, help="renders per row (default 7)")
    parser.add_argument("--code", type=Path, default=ROOT,
                        help="checkout whose addon/ to run (its native module is the one "
                             "installed in the Python that runs this script)")
    parser.add_argument("--cameras", action="store_true",
                        help="only the table per camera type (pinhole, orthographic, panoramas)")
    parser.add_argument("--no-f12", dest="f12", action="store_false",
                        help="skip the F12 table (Blender's Cycles with and without splats)")
    args = parser.parse_args()
    args.f12 = args.f12 and args.code.resolve() == ROOT
    args.repeats = args.repeats or (3 if args.quick else 7)
    import_code(args.code.resolve())
    if args.cameras:
        camera_table(args)
        return
    main_table(args)
    if args.more:
        more_tables(args)
    if args.f12:
        f12_table(args)


def f12_table(args) -> None:
    """The F12 overhead split, from this checkout's bench_render_with_meshes (it needs bpy)."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import bench_render_with_meshes as f12

    print(f"\nF12 at 1280x720, Cycles CPU 4 samples; medians of {args.repeats} interleaved "
          "pairs without and with splats (ms)", flush=True)
    f12.print_table([(path.stem, f12.f12_overhead(str(path), repeat=args.repeats))
                     for path in (PLAYBOT, DEMO) if path.exists()])


if __name__ == "__main__":
    main()
