"""What the splats add to an F12 frame (meshes in Cycles at low samples, plus splats), split into
its parts, and the frame's peak memory.

    .venv/bin/python benchmarks/bench_render_with_meshes.py [--size 1280x720] [--samples 4]
        [--splats FILE ...] [--random N ...] [--repeat 5]

The scene is examples/render_headless.py's (a monkey and a pedestal with the splats, a sun);
`--splats` swaps the splats (default: ../shared/data/splats/playbot_125k_sh2.ply when it is
there, and the demo scene), `--random N` uses N random Gaussians about the origin. For each
splat set it renders the same frame as F12 does (`bpy.ops.render.render()`, into the Render
Result, no file written) with the splats switched off and the compositor bridge removed (Blender
alone, as a scene without splats renders) and with them on, interleaved (off, on, off, on, ...),
and prints medians (ms) of where the difference goes:

    gather    splats from the render's depsgraph (world space; cached per object, so this is
              the cost of a frame whose splats did not change: "first" is the first render's)
    read      the meshes' colour and depth: Render Result -> float EXR in a RAM folder
              (Blender's Image.save_render) -> numpy views of its rows (addon.core.images.exr_scanlines)
    colour    scene-linear <-> display sRGB of the mesh layer and of the pixels the splats
              changed (addon.core.colour, native, on every core)
    native    the native compositor (projection, sort, binning, per-pixel composite)
    write     the composite -> the helper scene's render result (RenderPass.rect.foreach_set)
    other     the rest of the difference: the helper scene's render and Blender's compositor
              pass (the Render Layers node of the helper scene feeding the output)
    extra CPU the process's CPU time (every thread) with splats minus without, medians of the
              pairs: steadier than the wall clock where other programs share the cores

and the frame's peak memory: the process's peak resident size during one frame above what it
held before it (Linux: /proc/self/clear_refs resets the peak), without and with splats, and the
peak of the NumPy arrays the add-on holds during the frame (tracemalloc). Memory is measured on
renders of its own, outside the timed ones.

`f12_overhead()` returns one scene's figures as a dict (benchmarks/bench_render.py reports them).

    .venv/bin/python benchmarks/bench_render_with_meshes.py --profile [--repeat 5]
        [--splats FILE] [--profile-out STATS]

times the add-on's own work inside an F12 instead (`addon_cost`): every handler it registered
and its engine's render (and the frame's steps within them: gather, read, prepare, compose,
write), calls and CPU ms per frame (the calling thread's, and the process's: the add-on's
native threads and the EXR Blender writes for it), medians of --repeat frames with splats on
and off; which handlers Blender called per frame, for which scene and depsgraph (an extra
render of the helper scene, or an extra depsgraph, shows there); `--profile-out` writes
cProfile stats of one more frame. The script runs unchanged in a real Blender
(`blender -b --factory-startup --python benchmarks/bench_render_with_meshes.py -- --profile
...`, with the repository and an abi3 `splatcore` importable) and in `bpy` 5.3 (Python 3.13),
and against an older checkout of the add-on (copy it there: it uses only what both have).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "examples"))  # render_headless: the scene

import bpy  # noqa: E402

import render_headless  # noqa: E402

PLAYBOT = ROOT.parent / "shared" / "data" / "splats" / "playbot_125k_sh2.ply"
DEMO = ROOT / "examples" / "demo_scene.ply"
PARTS = ("gather", "read", "colour", "native", "write")


def _register() -> None:
    if not hasattr(bpy.types, "SPLAT_OT_import_splats"):
        import addon

        addon.register()


def _kilobytes(field: str) -> int | None:
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith(field + ":"):
                    return int(line.split()[1])
    except OSError:
        pass
    return None


def _reset_peak_rss() -> int | None:
    """Reset the process's peak resident size (Linux); returns the resident size now (kB)."""
    try:
        with open("/proc/self/clear_refs", "w") as clear:
            clear.write("5")
    except OSError:
        return None
    return _kilobytes("VmRSS")


def _render(cpu: list[float] | None = None) -> float:
    """One F12; returns its wall-clock ms (and appends the process's CPU ms, all threads, to
    `cpu`: on a shared machine the CPU time moves less than the wall clock)."""
    start, start_cpu = time.perf_counter(), time.process_time()
    assert bpy.ops.render.render() == {"FINISHED"}
    if cpu is not None:
        cpu.append(1000 * (time.process_time() - start_cpu))
    return 1000 * (time.perf_counter() - start)


def _use_splats(scene, on: bool) -> None:
    """Splats on (with the compositor bridge), or off with no bridge: Blender alone."""
    from addon.blender.render import compositor_bridge

    scene.splat_render.enabled = on
    if on:
        compositor_bridge.ensure_bridge(scene)
    else:
        compositor_bridge.remove_bridge(scene)


def _frame_memory(scene, with_splats: bool) -> dict:
    """Peak resident size above the resting one (MB) and NumPy's peak (MB) for one frame."""
    _use_splats(scene, with_splats)
    before = _reset_peak_rss()
    tracemalloc.start()
    try:
        _render()
        numpy_peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    peak = _kilobytes("VmHWM")
    rss = None if before is None or peak is None else (peak - before) / 1024
    return {"rss_mb": rss, "numpy_mb": numpy_peak / 2**20}


def build(splats: str | None = None, *, random: int = 0, size: str = "1280x720",
          samples: int = 4):
    """The headless example's scene with `splats` (a file) or `random` random Gaussians."""
    _register()
    from addon.blender import splat_object

    scene_args = argparse.Namespace(splats=str(splats or DEMO), engine="CYCLES", size=size,
                                    samples=samples, frames=1, out=tempfile.mkdtemp(), save="")
    render_headless.build_scene(bpy, scene_args)
    scene = bpy.context.scene
    if random:
        import numpy as np

        sys.path.insert(0, str(ROOT / "tests"))
        from scenes import fast_random_gaussians

        for obj in [o for o in scene.objects if splat_object.is_splat_object(o)]:
            bpy.data.objects.remove(obj)
        splat_object.create_splat_object(
            fast_random_gaussians(np.random.default_rng(0), random, degree=1), "Random")
    return scene


def f12_overhead(splats: str | None = None, *, random: int = 0, size: str = "1280x720",
                 samples: int = 4, repeat: int = 5) -> dict:
    """One scene's F12 figures: medians (ms) of Blender alone ("blender"), with splats
    ("with_splats"), their difference ("extra", the median of the interleaved pairs' own
    differences), its parts (PARTS and "other"), the process CPU time the splats add
    ("extra_cpu", the same way), the first render's gather ("gather_first"), the splat count,
    and the frame's peak memory (MB): "rss_plain_mb", "rss_splats_mb",
    "numpy_splats_mb" (see the module docstring)."""
    from addon.blender.render import hooks
    from addon.blender import splat_object

    scene = build(splats, random=random, size=size, samples=samples)
    count = sum(len(o.data.vertices) for o in scene.objects if splat_object.is_splat_object(o))
    _use_splats(scene, True)
    _render()  # gathers the splats: later frames find them in the cache
    first = dict(hooks.last_stats)
    plain, with_splats, stats, plain_cpu, splats_cpu = [], [], [], [], []
    for _ in range(repeat):
        _use_splats(scene, False)
        plain.append(_render(plain_cpu))
        _use_splats(scene, True)
        with_splats.append(_render(splats_cpu))
        stats.append(dict(hooks.last_stats))
    median = statistics.median
    result = {
        "splats": count, "size": size, "blender": median(plain), "with_splats": median(with_splats),
        "extra": median([s - p for s, p in zip(with_splats, plain)]),
        "extra_cpu": median([s - p for s, p in zip(splats_cpu, plain_cpu)]),
        "gather": median([s.get("gather_ms", 0.0) for s in stats]),
        "read": median([s.get("save_ms", 0.0) + s.get("read_ms", 0.0) for s in stats]),
        "colour": median([s.get("colour_ms", 0.0) for s in stats]),
        "native": median([s.get("native_ms", 0.0) for s in stats]),
        "write": median([s.get("result_ms", 0.0) for s in stats]),
        "gather_first": first.get("gather_ms", 0.0),
    }
    result["other"] = result["extra"] - sum(result[p] for p in PARTS)
    plain_memory = _frame_memory(scene, with_splats=False)
    splat_memory = _frame_memory(scene, with_splats=True)
    result.update(rss_plain_mb=plain_memory["rss_mb"], rss_splats_mb=splat_memory["rss_mb"],
                  numpy_splats_mb=splat_memory["numpy_mb"])
    return result


# ------------------------------------------------------------------ the add-on's own work (--profile)

class _Meter:
    """CPU time and calls per name: the calling thread's CPU (`time.thread_time`) and the
    process's (every thread: the add-on's native threads, and Blender's work the add-on asks
    for, such as the EXR it has Blender write)."""

    def __init__(self) -> None:
        self.rows: dict[str, list[float]] = {}   # name -> [calls, thread ms, process ms]

    def wrap(self, name: str, function):
        def timed(*args, **kwargs):
            thread, process = time.thread_time(), time.process_time()
            try:
                return function(*args, **kwargs)
            finally:
                row = self.rows.setdefault(name, [0, 0.0, 0.0])
                row[0] += 1
                row[1] += 1000 * (time.thread_time() - thread)
                row[2] += 1000 * (time.process_time() - process)
        timed.__wrapped__ = function
        return timed


def _handler_lists():
    for kind in dir(bpy.app.handlers):
        handlers = getattr(bpy.app.handlers, kind)
        if isinstance(handlers, list):
            yield kind, handlers


def _instrument(meter: _Meter, events: list) -> None:
    """Every handler the add-on registered timed by `meter`; Blender's handler calls recorded
    in `events` as (handler, scene, depsgraph mode); the engine's render and the frame's
    main steps timed (an unchanged `__wrapped__` marks what is already wrapped)."""
    from addon.blender.render import hooks

    for kind, handlers in _handler_lists():
        for i, function in enumerate(list(handlers)):
            module = getattr(function, "__module__", "") or ""
            if module.startswith("addon") and not hasattr(function, "__wrapped__"):
                short = module.rsplit(".", 1)[-1]
                handlers[i] = bpy.app.handlers.persistent(  # through a file load too
                    meter.wrap(f"{kind}: {short}.{function.__name__}", function))
        if kind in ("version_update", "_version_update") or kind.startswith("_"):
            continue

        def record(*args, _kind=kind):
            scene = args[0] if args and hasattr(args[0], "render") else None
            depsgraph = args[1] if len(args) > 1 else None
            events.append((_kind, getattr(scene, "name", None),
                           getattr(depsgraph, "mode", None)))
        handlers.append(bpy.app.handlers.persistent(record))
    engine = hooks.SplatRenderEngine
    if not hasattr(engine.render, "__wrapped__"):
        timed = meter.wrap("engine: render (all of it)", engine.render)

        def render(self, depsgraph):  # Blender passes what the signature names
            return timed(self, depsgraph)
        render.__wrapped__ = timed
        engine.render = render
    for name in ("capture_frame", "read_render_layer", "compose", "write_result", "prepare"):
        function = getattr(hooks, name, None)
        if function is not None and not hasattr(function, "__wrapped__"):
            setattr(hooks, name, meter.wrap(f"  {name}", function))
    from addon.blender.render import state
    for module in (state, hooks):
        function = getattr(module, "capture_frame", None)
        if function is not None and not hasattr(function, "__wrapped__"):
            setattr(module, "capture_frame", meter.wrap("  capture_frame", function))
    gather_module = state.gather
    if not hasattr(gather_module.gather, "__wrapped__"):
        gather_module.gather = meter.wrap("    gather", gather_module.gather)


def addon_cost(splats: str | None = None, *, size: str = "1280x720", samples: int = 4,
               repeat: int = 3, profile_out: str | None = None) -> dict:
    """The add-on's own work in an F12, handler by handler: the calls, the calling thread's
    CPU ms and the process's CPU ms of each, per frame (medians of `repeat` frames after a
    warm-up), for the scene with splats on and with them off (the bridge removed); the
    handler calls Blender made per frame (event, scene, depsgraph mode: an extra render of the
    helper scene or an extra depsgraph shows there); and each frame's wall and process CPU
    ms. With `profile_out`, one more frame with splats under cProfile, its stats written
    there."""
    scene = build(splats, size=size, samples=samples)
    meter, events = _Meter(), []
    _instrument(meter, events)
    result: dict = {}
    for on in (True, False):
        _use_splats(scene, on)
        _render()  # warm-up: the gather cache, Cycles' kernels
        frames, walls, cpus, event_lists = [], [], [], []
        for _ in range(repeat):
            meter.rows.clear()
            events.clear()
            cpu: list[float] = []
            walls.append(_render(cpu))
            cpus.append(cpu[0])
            frames.append({k: list(v) for k, v in meter.rows.items()})
            event_lists.append(list(events))
        names = sorted({n for f in frames for n in f})
        median = statistics.median
        rows = {n: [median(f.get(n, [0, 0.0, 0.0])[i] for f in frames) for i in range(3)]
                for n in names}
        counted: dict = {}
        for event in event_lists[-1]:
            counted[event] = counted.get(event, 0) + 1
        result["on" if on else "off"] = {"rows": rows, "events": counted,
                                         "wall": median(walls), "cpu": median(cpus),
                                         "walls": walls, "cpus": cpus}
    if profile_out:
        import cProfile

        _use_splats(scene, True)
        profiler = cProfile.Profile()
        profiler.enable()
        _render()
        profiler.disable()
        profiler.dump_stats(profile_out)
    return result


def print_cost(result: dict) -> None:
    for key in ("on", "off"):
        r = result[key]
        print(f"\nsplats {key}: F12 wall {r['wall']:.0f} ms {[round(w) for w in r['walls']]}, "
              f"process CPU {r['cpu']:.0f} ms {[round(c) for c in r['cpus']]}")
        print("| add-on call | calls | thread CPU ms | process CPU ms |")
        print("| --- | --- | --- | --- |")
        for name, (calls, thread, process) in r["rows"].items():
            print(f"| {name} | {calls:g} | {thread:.1f} | {process:.1f} |")
        print("handler calls (handler, scene, depsgraph mode): count")
        for (kind, scene, mode), count in sorted(r["events"].items(), key=str):
            print(f"  {kind}, {scene}, {mode}: {count}")


HEADER = ("splats", "Blender", "with splats", "extra", *PARTS, "other", "extra CPU",
          "gather (first)", "peak RSS +MB (off / on)", "NumPy peak MB")


def table_row(name: str, r: dict) -> str:
    def mb(value):
        return "n/a" if value is None else f"{value:.0f}"

    cells = [f"{name} ({r['splats']:,})", *(f"{r[k]:.0f}" for k in
             ("blender", "with_splats", "extra", *PARTS, "other", "extra_cpu", "gather_first")),
             f"{mb(r['rss_plain_mb'])} / {mb(r['rss_splats_mb'])}", mb(r["numpy_splats_mb"])]
    return "| " + " | ".join(cells) + " |"


def print_table(rows: list[tuple[str, dict]]) -> None:
    print("| " + " | ".join(HEADER) + " |")
    print("|" + " --- |" * len(HEADER))
    for name, r in rows:
        print(table_row(name, r), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--size", default="1280x720")
    parser.add_argument("--samples", type=int, default=4)
    parser.add_argument("--splats", nargs="*",
                        default=[str(p) for p in (PLAYBOT, DEMO) if p.exists()])
    parser.add_argument("--random", nargs="*", type=int, default=[])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--profile", action="store_true",
                        help="the add-on's own work per F12, handler by handler (the first "
                             "--splats file; see addon_cost)")
    parser.add_argument("--profile-out", default=None, help="cProfile stats of one more frame")
    # inside a real Blender (`blender -b --python FILE -- ARGS`) the arguments follow "--"
    args = parser.parse_args(sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv
                             else sys.argv[1:])
    _register()
    if args.profile:
        result = addon_cost(args.splats[0] if args.splats else None, size=args.size,
                            samples=args.samples, repeat=args.repeat,
                            profile_out=args.profile_out)
        print_cost(result)
        return
    from addon.core.native import cpu_count

    print(f"F12 at {args.size}, Cycles CPU {args.samples} samples, {cpu_count()} cores; "
          f"medians of {args.repeat} interleaved pairs (ms)", flush=True)
    rows = []
    for path in args.splats:
        rows.append((Path(path).stem, f12_overhead(path, size=args.size, samples=args.samples,
                                                   repeat=args.repeat)))
    for n in args.random:
        rows.append(("random", f12_overhead(random=n, size=args.size, samples=args.samples,
                                            repeat=args.repeat)))
    print_table(rows)


if __name__ == "__main__":
    main()
