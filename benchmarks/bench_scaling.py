"""Scaling benchmark (issue 37): a training step's and a render's phases at each thread count,
and how much of each phase is serial.

    .venv/bin/python benchmarks/bench_scaling.py                       # threads 1 and 2
    .venv/bin/python benchmarks/bench_scaling.py --threads 1 2 4 8 16  # a bigger machine
    .venv/bin/python benchmarks/bench_scaling.py --only train          # or --only render
    .venv/bin/python benchmarks/bench_scaling.py --only render --sizes 3840x2160 7680x4320
    .venv/bin/python benchmarks/bench_scaling.py --code DIR            # another checkout's code
                                    # (DIR/addon, and DIR/splatcore.abi3.so if there): before/after

Training: the demo scene (examples/demo_colmap, 480x360, strategy "default", seed 0) trained
to --from-step once (the checkpoint is cached under out/), then --steps steps from there at
each thread count, the counts taking turns --repeats times (the same steps each time: training
is identical for any thread count). Phases: the photo (fetch, halve), the forward's project,
sort, bin and composite (its native timers), the loss, the backward's compositor and
per-Gaussian passes, Adam, densification (the strategy's hooks), and the Python glue (the rest
of the step). Evaluation (the held-out views rendered and scored, what a run until done does
every 500 steps) is timed once per turn, per call.
Render: PLAYBOT (125k Gaussians, SH degree 2) at each --sizes, through `renderer.render` as its
callers use it (new images each frame): Python (arguments, image allocation), project, sort, bin
and composite (native timers); "first touch" is the composite's time over what it takes into
images that were written before (the page faults of fresh images); then the viewport's output
conversion (`render_view` after its render; needs bpy, --no-viewport skips it).

Columns: ms per step (or frame), the median over the turns, at each thread count: at 1 thread
the calling thread's CPU time (all the work runs on it: steady on a busy machine; code without
`pool_profile(cpu_clock=)` gives wall time), at more the wall time; the speed-up over 1
thread; the serial fraction s that Amdahl's law gives from it, s = (T_n / T_1 - 1/n) / (1 - 1/n);
and "serial @1": at 1 thread, the phase's time outside the
native thread pool's parallel sections (`native.pool_profile`), i.e. work that no thread count
shortens, measured without another core (steady on a busy machine; code without the profile
shows "-"); "serial @n" the same at n threads (work that grows with the thread count shows
there, even with more threads than cores). Below each table: parallel sections per step and,
at each count above 1, the time their threads spent waiting in them (waking up, the tail after
the last chunk), and page faults.
Numbers only, never a test; on a shared machine compare runs taken back to back.
"""

from __future__ import annotations

import argparse
import inspect
import os
import resource
import statistics
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
DEMO_COLMAP = ROOT / "examples" / "demo_colmap"
PLAYBOT = ROOT.parent / "shared" / "data" / "splats" / "playbot_125k_sh2.ply"


def import_code(code: Path) -> None:
    """Import the add-on (and a splatcore.abi3.so beside it, if any) from `code`."""
    sys.path.insert(0, str(code))
    sys.path.insert(0, str(ROOT / "benchmarks"))  # bench_render's table and camera


# ---------------------------------------------------------------- probes


class Probe:
    """Wall ms, ms inside the native pool's parallel sections and page faults, summed per
    phase name (`time(name, function, ...)`, or `add` for native timers). The pool's totals
    (sections, waiting) count what runs inside the phase `counted`."""

    def __init__(self, counted: str, cpu: bool = False) -> None:
        from addon.core import native

        self.profile = getattr(native, "pool_profile", None)
        # One thread: the calling thread's CPU clock, here and in the native stages' timers
        # (all the work runs on that thread; a busy machine does not inflate it).
        self.cpu = cpu
        self.clock = time.thread_time if cpu else time.perf_counter
        if cpu and self.profile is not None and \
                "cpu_clock" not in inspect.signature(self.profile).parameters:
            self.clock = time.perf_counter  # code whose stages only have the wall clock
        self.ms: dict[str, float] = defaultdict(float)
        self.pool: dict[str, float] = defaultdict(float)
        self.faults: dict[str, float] = defaultdict(float)
        self.pool_totals = {"jobs": 0, "busy_ms": 0.0, "offered_ms": 0.0}
        self._stack: list[str] = []
        self.counted = counted

    def start(self) -> None:
        """Forget what was timed so far (a warm-up) and start profiling."""
        for sums in (self.ms, self.pool, self.faults):
            sums.clear()
        self.pool_totals = dict.fromkeys(self.pool_totals, 0)
        if self.profile:
            self._enable()

    def _enable(self) -> dict:
        return self.profile(True, cpu_clock=True) if self.clock is time.thread_time \
            else self.profile(True)

    def stop(self) -> None:
        if self.profile:
            self._take()
            self.profile(False)

    def _take(self) -> float:
        """ms inside parallel sections since the last take (0 without the profile)."""
        if not self.profile:
            return 0.0
        counters = self._enable()
        if self._stack and self._stack[0] == self.counted:
            for key in self.pool_totals:
                self.pool_totals[key] += counters[key]
        return counters["inside_ms"]

    def time(self, name: str, function, *args, **kwargs):
        outer = self._take()  # belongs to the enclosing phase
        if self._stack:
            self.pool[self._stack[-1]] += outer
        self._stack.append(name)
        faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        start = self.clock()
        try:
            return function(*args, **kwargs)
        finally:
            self.ms[name] += 1e3 * (self.clock() - start)
            self.faults[name] += resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults
            self.pool[name] += self._take()
            self._stack.pop()

    def add(self, name: str, ms: float, pool_ms: float | None, inside: str) -> None:
        """A native stage `name` of `ms` (of which `pool_ms` in parallel sections) timed
        inside the phase `inside`, which it is taken out of."""
        self.ms[name] += ms
        self.ms[inside] -= ms
        if pool_ms is not None and self.profile:
            self.pool[name] += pool_ms
            self.pool[inside] -= pool_ms


def amdahl(t1: float, tn: float, n: int) -> float:
    """The serial fraction s with tn = t1 (s + (1 - s) / n)."""
    return (tn / t1 - 1.0 / n) / (1.0 - 1.0 / n)


def scaling_table(title: str, phases: list[str], runs: dict[int, list[Probe]], per: float,
                  unit: str) -> None:
    """Median ms per `unit` (each probe's sums divided by `per`) by phase and thread count."""
    from bench_render import table

    counts = sorted(runs)
    median = {n: {p: statistics.median(r.ms[p] / per for r in runs[n]) for p in phases}
              for n in counts}
    base = counts[0] if counts[0] == 1 else None
    profiled = base is not None and runs[base][0].profile is not None
    rows = []
    for p in phases:
        row = [p] + [f"{median[n][p]:.2f}" for n in counts]
        for n in counts[1:]:
            if base is None or median[base][p] <= 0 or median[n][p] <= 0:
                row += ["-", "-"]
                continue
            row += [f"{median[base][p] / median[n][p]:.2f}",
                    f"{amdahl(median[base][p], median[n][p], n):.2f}"]
        if profiled:
            serial = {n: statistics.median((r.ms[p] - r.pool[p]) / per for r in runs[n])
                      for n in counts}
            share = serial[base] / median[base][p] if median[base][p] > 0 else 0.0
            row += [f"{serial[base]:.2f}", f"{100 * share:.0f} %"]
            row += [f"{serial[n]:.2f}" for n in counts[1:]]
        else:
            row += ["-", "-"] + ["-" for _ in counts[1:]]
        rows.append(row)
    header = ["phase"] + [f"ms @{n}" for n in counts]
    for n in counts[1:]:
        header += [f"x @{n}", f"s @{n}"]
    header += ["serial @1 ms", "of phase"] + [f"serial @{n}" for n in counts[1:]]
    print(title)
    table(rows, header)
    notes = []
    for n in counts:
        probes = runs[n]
        if probes[0].profile is None:
            continue
        jobs = statistics.median(r.pool_totals["jobs"] / per for r in probes)
        wait = statistics.median((r.pool_totals["offered_ms"] - r.pool_totals["busy_ms"]) / per
                                 for r in probes)
        notes.append(f"@{n}: {jobs:.0f} parallel sections per {unit}" +
                     (f", their threads waiting {wait:.2f} ms per {unit} "
                      f"({1e3 * wait / max(jobs, 1):.0f} us a section)" if n > 1 else ""))
    last = runs[counts[-1]]
    faults = {name: statistics.median(r.faults[name] / per for r in last)
              for name in last[0].faults}
    notes.append(f"page faults per {unit} @{counts[-1]}: " + ", ".join(
        f"{name} {value:.0f}" for name, value in faults.items()))
    print(";\n".join(notes) + "\n")


# ---------------------------------------------------------------- training


def demo_dataset():
    from addon.core.colmap import read_colmap
    from addon.core.train.dataset import ColmapDataset

    dataset = ColmapDataset(read_colmap(DEMO_COLMAP, image_folder="images"))
    dataset.preload()
    return dataset


def train_checkpoint(dataset, from_step: int, total: int) -> Path:
    """The demo's trainer at `from_step` of a `total`-step run (strategy "default", seed 0),
    trained once on 2 threads and cached."""
    from addon.core.train.trainer import Trainer, TrainConfig

    path = ROOT / "out" / f"bench_scaling_demo_default_{from_step}_of_{total}.npz"
    if not path.exists():
        path.parent.mkdir(exist_ok=True)
        print(f"(training the demo scene to step {from_step} for {path.name})", file=sys.stderr)
        trainer = Trainer(dataset, TrainConfig(strategy="default", steps=total, seed=0, threads=2))
        for _ in trainer.run(from_step):
            pass
        trainer.save_checkpoint(path)
    return path


TRAIN_PHASES = ["photo", "project", "sort", "bin", "composite", "loss", "bw composite",
                "bw per-Gaussian", "adam", "densification", "Python glue", "step"]


def profile_training(dataset, checkpoint: Path, steps: int, threads: int) -> tuple[Probe, float, int]:
    """`steps` steps from the checkpoint on `threads` threads, timed by phase; and the time of
    one evaluation (ms) and the Gaussian count at the end."""
    from addon.core.train import kernels, optimizer
    from addon.core.train.trainer import Trainer

    trainer = Trainer.load_checkpoint(checkpoint, dataset)
    trainer.config.threads = threads
    probe = Probe("step", cpu=threads == 1)
    # Wrapped where the trainer looks them up: the kernels module, the parameters' class, the
    # trainer's and strategy's own methods.
    originals = (kernels.render_train, kernels.l1_ssim_loss, kernels.backward,
                 optimizer.GaussianParameters.adam_step)

    def render_train(*args, **kwargs):
        result, state = probe.time("forward", originals[0], *args, **kwargs)
        s = result.stats
        for stage in ("project", "sort", "bin", "composite"):
            probe.add(stage, s[f"ms_{stage}"], s.get(f"ms_pool_{stage}"), "forward")
        return result, state

    def backward(*args, **kwargs):
        grads = probe.time("backward", originals[2], *args, **kwargs)
        s = grads.stats
        probe.add("bw composite", s["ms_composite"], s.get("ms_pool_composite"), "backward")
        probe.add("bw per-Gaussian", s["ms_project"], s.get("ms_pool_project"), "backward")
        return grads

    kernels.render_train = render_train
    kernels.l1_ssim_loss = lambda *a, **k: probe.time("loss", originals[1], *a, **k)
    kernels.backward = backward
    optimizer.GaussianParameters.adam_step = (
        lambda self, *a, **k: probe.time("adam", originals[3], self, *a, **k))
    view, after_backward, after_step = (trainer.training_view, trainer.strategy.after_backward,
                                        trainer.strategy.after_step)
    trainer.training_view = lambda *a: probe.time("photo", view, *a)
    trainer.strategy.after_backward = lambda *a: probe.time("densification", after_backward, *a)
    trainer.strategy.after_step = lambda *a: probe.time("densification", after_step, *a)
    try:
        trainer.train_step()  # warm-up (pool threads, buffers), not counted
        probe.start()
        for _ in range(steps):
            probe.time("step", trainer.train_step)
        probe.stop()
        start = time.perf_counter()
        trainer.evaluate()
        evaluation = 1e3 * (time.perf_counter() - start)
    finally:
        (kernels.render_train, kernels.l1_ssim_loss, kernels.backward,
         optimizer.GaussianParameters.adam_step) = originals
    # The timed calls' leftovers (the forward's and backward's Python and arguments) and the
    # rest of the step are the glue. Pool times are exclusive (each phase's own).
    inner = TRAIN_PHASES[:-2]
    probe.ms["Python glue"] = probe.ms["step"] - sum(probe.ms[p] for p in inner)
    glue_pool = probe.pool["step"] + probe.pool["forward"] + probe.pool["backward"]
    probe.pool["Python glue"] = glue_pool
    probe.pool["step"] = glue_pool + sum(probe.pool[p] for p in inner)
    return probe, evaluation, len(trainer)


def training_table(args) -> None:
    dataset = demo_dataset()
    checkpoint = train_checkpoint(dataset, args.from_step, args.total_steps)
    runs: dict[int, list[Probe]] = defaultdict(list)
    evaluations: dict[int, list[float]] = defaultdict(list)
    count = 0
    for turn in range(args.repeats):
        for threads in args.threads:
            probe, evaluation, count = profile_training(dataset, checkpoint, args.steps, threads)
            runs[threads].append(probe)
            evaluations[threads].append(evaluation)
            print(f"turn {turn + 1}, {threads} threads: {probe.ms['step'] / args.steps:.2f} ms a "
                  f"step", file=sys.stderr, flush=True)
    size = dataset.cameras[0]
    scaling_table(f"Training the demo scene at {size.width}x{size.height} (strategy 'default'), "
                  f"steps {args.from_step + 1}-{args.from_step + args.steps + 1} of "
                  f"{args.total_steps} (the first one a warm-up), {count} Gaussians at the end; "
                  f"ms per step, median of {args.repeats} turns",
                  TRAIN_PHASES, runs, args.steps, "step")
    line = ", ".join(f"{statistics.median(evaluations[n]):.0f} ms @{n}" for n in sorted(evaluations))
    print(f"Evaluation ({len(dataset.test_indices)} held-out views rendered and scored), per call: "
          f"{line}\n")


# ---------------------------------------------------------------- rendering

RENDER_PHASES = ["Python", "project", "sort", "bin", "composite", "first touch", "render",
                 "output conversion"]


def profile_render(gaussians, camera, threads: int, repeats: int, viewport) -> Probe:
    """`repeats` frames as `renderer.render` makes them, one more into images it has written
    before (the composite without the page faults of fresh images), and the viewport's
    conversion of a frame (when `viewport` is the module)."""
    from addon.core import native
    from addon.core.render import renderer

    probe = Probe("render", cpu=threads == 1)
    renderer.render(gaussians, camera, threads=threads)  # warm-up: the pool, kept buffers
    probe.start()
    reused = [np.empty((camera.height, camera.width, 3), np.float32),
              np.empty((camera.height, camera.width), np.float32),
              np.empty((camera.height, camera.width), np.float32)]
    for a in reused:
        a.fill(0)
    warm = 0.0
    for _ in range(repeats):
        result = probe.time("render", renderer.render, gaussians, camera, threads=threads)
        s = result.stats
        for stage in ("project", "sort", "bin", "composite"):
            probe.add(stage, s[f"ms_{stage}"], s.get(f"ms_pool_{stage}"), "render")
        stats = native.render(gaussians, camera, None, None, None, *reused, sh_degree=None,
                              near=0.01, antialiased=False, threads=threads)
        warm += stats["ms_composite"]
    # The page faults of fresh images happen inside the (parallel) composite.
    probe.ms["first touch"] = max(probe.ms["composite"] - warm, 0.0)
    probe.ms["composite"] -= probe.ms["first touch"]
    if probe.profile:
        probe.pool["first touch"] = probe.ms["first touch"]
        probe.pool["composite"] -= probe.ms["first touch"]
    probe.ms["Python"] = probe.ms["render"]  # what is left of the call: arguments, allocation
    probe.pool["Python"] = probe.pool["render"]
    probe.ms["render"] = sum(probe.ms[p] for p in RENDER_PHASES[:6])
    probe.pool["render"] = sum(probe.pool[p] for p in RENDER_PHASES[:6])
    if viewport is not None:
        original = viewport.render
        viewport.render = lambda *a, **k: probe.time("viewport render", original, *a, **k)
        window = camera_window_matrix(camera)
        try:
            for _ in range(repeats):
                probe.time("output conversion", viewport.render_view, gaussians, camera, window,
                           threads=threads)
        finally:
            viewport.render = original
        probe.ms["output conversion"] -= probe.ms.pop("viewport render")
        probe.pool.pop("viewport render")
    probe.stop()
    return probe


def camera_window_matrix(camera) -> np.ndarray:
    """An OpenGL projection matrix for `camera`'s pinhole (near 0.01, far 100)."""
    near, far = 0.01, 100.0
    w, h = camera.width, camera.height
    return np.array([[2 * camera.fx / w, 0, 1 - 2 * camera.cx / w, 0],
                     [0, 2 * camera.fy / h, 2 * camera.cy / h - 1, 0],
                     [0, 0, -(far + near) / (far - near), -2 * far * near / (far - near)],
                     [0, 0, -1, 0]])


def render_tables(args) -> None:
    from addon.core import splat_io
    from bench_render import playbot_camera

    viewport = None
    if args.viewport:
        try:
            from addon.blender import viewport
        except ImportError as error:  # no bpy
            print(f"(no viewport conversion: {error})\n")
    gaussians = splat_io.load(str(PLAYBOT))
    for width, height in args.sizes:
        camera = playbot_camera(width, height)
        runs: dict[int, list[Probe]] = defaultdict(list)
        peaks: dict[int, float] = {}
        for turn in range(args.turns):
            for threads in args.threads:
                probe = profile_render(gaussians, camera, threads, args.frames, viewport)
                runs[threads].append(probe)
                print(f"{width}x{height}, turn {turn + 1}, {threads} threads: "
                      f"{probe.ms['render'] / args.frames:.1f} ms a frame", file=sys.stderr,
                      flush=True)
        from addon.core.render import renderer

        for threads in args.threads:
            peaks[threads] = renderer.render(gaussians, camera, threads=threads).stats.get(
                "peak_bytes", 0) / 2**20
        scaling_table(f"Rendering PLAYBOT ({len(gaussians)} Gaussians, SH degree "
                      f"{gaussians.degree}) at {width}x{height}: ms per frame, median of "
                      f"{args.turns} turns of {args.frames} frames",
                      RENDER_PHASES if viewport else RENDER_PHASES[:-1], runs, args.frames,
                      "frame")
        print("the renderer's working memory at its largest: " + ", ".join(
            f"{peaks[n]:.0f} MiB @{n}" for n in sorted(peaks)) + "\n")


def size(text: str) -> tuple[int, int]:
    width, height = text.lower().split("x")
    return int(width), int(height)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2],
                        help="thread counts (the first should be 1: the base of the speed-ups)")
    parser.add_argument("--only", choices=("train", "render"), default=None)
    parser.add_argument("--from-step", type=int, default=1000,
                        help="profile training from this step of the run (cached checkpoint)")
    parser.add_argument("--total-steps", type=int, default=1500,
                        help="the run's step count (its schedules depend on it)")
    parser.add_argument("--steps", type=int, default=200, help="training steps timed per turn")
    parser.add_argument("--repeats", type=int, default=3, help="training turns")
    parser.add_argument("--sizes", type=size, nargs="+", default=[(1920, 1080), (3840, 2160)])
    parser.add_argument("--turns", type=int, default=3, help="render turns")
    parser.add_argument("--frames", type=int, default=5, help="frames per render turn")
    parser.add_argument("--no-viewport", dest="viewport", action="store_false",
                        help="without the viewport's output conversion (it imports bpy)")
    parser.add_argument("--code", type=Path, default=ROOT,
                        help="the checkout whose add-on (and splatcore.abi3.so, if there) runs")
    args = parser.parse_args()
    import_code(args.code.resolve())
    print(f"code: {args.code}; {os.cpu_count()} cores; load average {os.getloadavg()[0]:.2f} "
          f"at the start\n")
    if args.only != "render":
        training_table(args)
    if args.only != "train":
        render_tables(args)
    print(f"load average {os.getloadavg()[0]:.2f} at the end")


if __name__ == "__main__":
    main()
