"""Long jobs, Blender-free: training as a job (a `Trainer` on a worker thread or the calling
thread, with progress, cancelling, snapshots of the Gaussians and checkpoints), work in stages on
the caller's thread (`StagedJob`), and how both report (`Progress`, `status_line`,
`ProgressPrinter`). The Blender side (`addon/blender/job_runner.py`) runs either kind from an
operator: a timer in the UI, blocking in scripts.

    job = TrainingJob(lambda job: Trainer(dataset, config), checkpoint="state.npz",
                      checkpoint_every=1000, snapshot_every=200)
    job.start()                      # a worker thread: the native kernels release the GIL
    while not job.done:
        p = job.progress()           # a consistent copy: step, loss, PSNR, Gaussians, ETA
        snap = job.take_snapshot()   # (step, Gaussians) every `snapshot_every` steps, else None
    job.cancel(); job.join()         # stops after the current step; the checkpoint is saved

    job.run()                        # the same work on the calling thread (scripts, background)

Thread safety: only the worker touches the `Trainer` while the job runs. Everything the job
publishes (progress, snapshots) is copied between two steps, under a lock, so a reader never sees
a half-updated or half-densified state. After `done`, `job.trainer` belongs to the caller again.

Progress numbers: `loss` and `psnr` are means over the last `window` training steps (a single
step's values depend on which view it drew); `eta` is the mean wall time of those steps times
the steps left (steps get slower as densification adds Gaussians, so early estimates are low;
a run until done has none: `until_done`, and `gain_per_minute` says how close it is to
stopping); `sizing` is the strategy's word for the count ("growing", "settled").
Held-out PSNR/SSIM (`Trainer.evaluate`) is computed once, at the end, unless cancelled.

On a worker thread (`start`, as in Blender's UI), a trainer set to every core (`threads` 0)
runs its kernels on one core fewer (`ui_kernel_threads`): the UI's main thread needs a core of
its own to stay responsive (issue 25: with every core busy, a 10 ms timer in Blender ran a
median 300 ms late). `run` on the calling thread (scripts, background) uses them all. A run
until done that stops because its gain stalled has finished (it is compacted, evaluated and
reported as done), not cancelled.
"""

from __future__ import annotations

import threading
import time
import traceback
from collections import deque
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Generator, Sequence

from .gaussians import Gaussians
from .native import cpu_count
from .priority import at_background_priority
from .threads import kernel_threads
from .train.trainer import CompactionReport, Evaluation, Trainer, compact

PHASES = ("waiting", "loading", "working", "training", "compacting", "evaluating", "saving", "done",
          "cancelled", "failed")


@dataclass
class Progress:
    phase: str = "waiting"  # one of PHASES
    message: str = ""
    step: int = 0  # the trainer's step (counts from the checkpoint when resumed)
    start_step: int = 0  # the step this job began at
    total: int = 0  # the step training stops at (until done: at the latest)
    until_done: bool = False  # no fixed step count: training stops when the gain stalls
    loss: float = float("nan")  # mean over the last `window` steps
    psnr: float = float("nan")  # training-view PSNR, mean over the last `window` steps
    gaussians: int = 0
    sizing: str = ""  # how the count changes ("growing", "settled"; "" if not said)
    gain_per_minute: float = float("nan")  # held-out PSNR gain over the last minute of checks
    sh_degree: int = 0
    elapsed: float = 0.0  # seconds since training (not loading) began
    seconds_per_step: float = float("nan")  # mean wall time of the last `window` steps
    eta: float | None = None  # seconds left, None until a few steps have run
    evaluation: Evaluation | None = None  # held-out PSNR/SSIM at the end
    prepared: float = 0.0  # while loading or working (a `StagedJob`): the fraction done

    @property
    def fraction(self) -> float:
        """Of the preparation while loading or working, else of the total steps (a resumed
        job at step 300 of 1,500 is 20 % done, not 0 %)."""
        if self.phase in ("waiting", "loading", "working"):
            return self.prepared
        if self.total <= 0:
            return 1.0 if self.finished else 0.0
        return min(max(self.step / self.total, 0.0), 1.0)

    @property
    def finished(self) -> bool:
        return self.phase in ("done", "cancelled", "failed")


def format_duration(seconds: float | None) -> str:
    """'1:02:03', '4:05' or '0:09'; '--' when unknown."""
    if seconds is None or not seconds == seconds or seconds < 0:
        return "--"
    s = int(round(seconds))
    h, rest = divmod(s, 3600)
    m, s = divmod(rest, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


def how_far(p: Progress) -> str:
    """How far a run is, said one way everywhere (status bar, sidebar, reports): "step 1,234 of
    7,000", or "step 1,234 (until done)" for a run whose stop rule, not a count, ends it."""
    return f"step {p.step:,} (until done)" if p.until_done else f"step {p.step:,} of {p.total:,}"


def status_line(p: Progress, title: str = "Training") -> str:
    """The one-line status shown in Blender's status bar (and printed in background mode)."""
    if p.phase == "failed":
        where = f" at step {p.step:,}" if p.total else ""
        return f"{title} failed{where}: {p.message}"
    if p.phase in ("waiting", "loading"):
        return f"{title}: {p.message or 'loading photos'}..."
    if p.phase == "working":
        return f"{title}: {p.message} ({100 * p.fraction:.0f} %)"
    if p.phase in ("cancelled", "done") and not p.total:  # no steps: a staged job, or none run
        return f"{title}: {p.message or p.phase}"
    if p.phase in ("compacting", "evaluating", "saving"):
        return f"{title}: {p.message or p.phase}..."
    parts = [f"{title} {how_far(p)}" + ("" if p.until_done else f" ({100 * p.fraction:.0f} %)")]
    if p.loss == p.loss:
        parts.append(f"loss {p.loss:.4f}")
    if p.psnr == p.psnr:
        parts.append(f"PSNR {p.psnr:.2f} dB")
    parts.append(f"{p.gaussians:,} Gaussians" + (f" ({p.sizing})" if p.sizing else ""))
    if p.seconds_per_step == p.seconds_per_step:
        parts.append(f"{1000 * p.seconds_per_step:.0f} ms/step")
    if p.until_done and p.gain_per_minute == p.gain_per_minute:
        parts.append(f"gaining {p.gain_per_minute:+.2f} dB/min")
    if p.phase == "training" and not p.until_done:
        parts.append(f"ETA {format_duration(p.eta)}")
    elif p.phase == "cancelled":
        parts.append("cancelled")
    if p.evaluation is not None and p.evaluation.views:
        parts.append(f"held-out PSNR {p.evaluation.psnr:.2f} dB, SSIM {p.evaluation.ssim:.3f}")
    return " | ".join(parts)


def compaction_note(job: "TrainingJob") -> str:
    """What compaction did, for a report ("" when it did not run)."""
    report = job.compaction
    if report is None:
        return ""
    b, a = report.before, report.after
    return (f"; compacted {b['gaussians']:,} -> {a['gaussians']:,} Gaussians, SH degree "
            f"{b['sh_degree']} -> {a['sh_degree']}, training-view PSNR {b['psnr']:.2f} -> "
            f"{a['psnr']:.2f} dB")


class JobCancelled(Exception):
    """Raised by `TrainingJob.loading` when the job was cancelled while it prepared."""


class TrainingJob:
    """Runs a `Trainer` to `steps` total steps. `trainer` is a Trainer or a callable
    `make(job) -> Trainer`, called on the worker (so loading photos does not block the caller
    either); it may call `job.loading(fraction, message)` to report, which raises
    `JobCancelled` once the job is cancelled (the job then ends "cancelled", with no trainer).

    steps: the step to stop at (None: the trainer's config.steps; 0: until done, as
        `Trainer.run`); it is written into the trainer's config.
    checkpoint: a path; saved every `checkpoint_every` steps (0: never in between) and at the
        end, also when cancelled after some steps (not when failed, nor when cancelled before
        the first step: an earlier checkpoint stays as it was).
    snapshot_every: publish a copy of the Gaussians every so many steps (0: only at the end).
    before_step(trainer): called on the worker before every step (e.g. a random background).
    after_training(trainer): called on the worker once training stops (cancelled or not),
        before compaction, evaluation and the checkpoint.
    on_progress(progress): called on the worker after every step and at each phase change.
    compact_after: run `train.compact` after training (not when cancelled).
    evaluate: compute held-out PSNR/SSIM at the end (not when cancelled) if there are test views.
    loading_message: what the progress says while `trainer` (a callable) makes the trainer.
    """

    def __init__(self, trainer: Trainer | Callable[["TrainingJob"], Trainer], *,
                 steps: int | None = None,
                 checkpoint: str | Path | None = None, checkpoint_every: int = 0,
                 snapshot_every: int = 0, window: int = 50,
                 before_step: Callable[[Trainer], None] | None = None,
                 after_training: Callable[[Trainer], None] | None = None,
                 on_progress: Callable[[Progress], None] | None = None,
                 compact_after: bool = False, evaluate: bool = True,
                 loading_message: str = "loading photos") -> None:
        self._make = trainer if callable(trainer) and not isinstance(trainer, Trainer) else None
        self.trainer: Trainer | None = None if self._make else trainer
        self.steps = steps
        self.checkpoint = Path(checkpoint) if checkpoint else None
        self.checkpoint_every = int(checkpoint_every)
        self.snapshot_every = int(snapshot_every)
        self.before_step = before_step
        self.after_training = after_training
        self.on_progress = on_progress
        self.compact_after = compact_after
        self.evaluate = evaluate
        self.loading_message = loading_message
        self.compaction: CompactionReport | None = None
        self.error: BaseException | None = None
        self.error_traceback = ""
        self.checkpoint_saved = False
        self.final: tuple[int, Gaussians] | None = None  # (step, Gaussians) once done
        self._lock = threading.Lock()
        self._cancel = threading.Event()
        self._done = threading.Event()
        self._progress = Progress()
        self._snapshot: tuple[int, Gaussians] | None = None
        self._window = deque(maxlen=max(1, int(window)))
        self._thread: threading.Thread | None = None
        self._held_until = 0.0  # time.monotonic(): no step before it (`hold`)

    # -- control ----------------------------------------------------------------------------
    def start(self) -> "TrainingJob":
        """Run on a daemon worker thread; returns at once."""
        if self._thread is not None:
            raise RuntimeError("the job has already been started")
        self._thread = threading.Thread(target=self._work, name="splat-training", daemon=True)
        self._thread.start()
        return self

    def run(self, *, raise_errors: bool = True) -> "TrainingJob":
        """Run on the calling thread until done. The worker's error, if any, is re-raised
        (`raise_errors`) or left in `error` for the caller to report."""
        if self._thread is not None or self._done.is_set():
            raise RuntimeError("the job has already been started")
        self._work()
        if self.error is not None and raise_errors:
            raise self.error
        return self

    def cancel(self) -> None:
        """Ask the worker to stop after the current step (it then saves the checkpoint)."""
        self._cancel.set()

    def hold(self, seconds: float) -> None:
        """No step for `seconds` from now (after the one running); a cancel ends the wait."""
        with self._lock:
            self._held_until = max(self._held_until, time.monotonic() + seconds)

    def poll(self, seconds: float = 0.0) -> None:
        """Nothing to do: the work runs on its own thread (see `StagedJob.poll`)."""

    @property
    def cancelled(self) -> bool:
        return self._cancel.is_set()

    def join(self, timeout: float | None = None) -> bool:
        """Wait for the worker; True once it has finished."""
        if self._thread is not None:
            self._thread.join(timeout)
        return self._done.is_set()

    @property
    def done(self) -> bool:
        return self._done.is_set()

    @property
    def running(self) -> bool:
        return self._thread is not None and not self._done.is_set()

    def loading(self, fraction: float, message: str) -> None:
        """For `make(job)`: report preparation progress; raises JobCancelled if cancelled."""
        if self._cancel.is_set():
            raise JobCancelled()
        self._set(phase="loading", message=message,
                  prepared=min(max(float(fraction), 0.0), 1.0))

    # -- what the caller reads ---------------------------------------------------------------
    def progress(self) -> Progress:
        with self._lock:
            return replace(self._progress)

    def take_snapshot(self) -> tuple[int, Gaussians] | None:
        """The newest published (step, Gaussians), once; None if nothing new since last time.
        The last state stays in `final` once the job is done (also after a failure, when the
        trainer's state was consistent enough to copy)."""
        with self._lock:
            snapshot, self._snapshot = self._snapshot, None
        return snapshot

    # -- the worker ----------------------------------------------------------------------------
    def _set(self, **changes) -> None:
        with self._lock:
            self._progress = replace(self._progress, **changes)
            progress = replace(self._progress)
        if self.on_progress is not None:
            self.on_progress(progress)

    def _publish(self, trainer: Trainer, *, final: bool = False) -> None:
        snapshot = (trainer.step, trainer.gaussians.copy())
        with self._lock:
            self._snapshot = snapshot
            if final:
                self.final = snapshot

    def _save_checkpoint(self, trainer: Trainer) -> None:
        if self.checkpoint is not None:
            self.checkpoint.parent.mkdir(parents=True, exist_ok=True)
            trainer.save_checkpoint(self.checkpoint)
            self.checkpoint_saved = True

    def _work(self) -> None:
        trainer = self.trainer
        try:
            if trainer is None:
                self._set(phase="loading", message=self.loading_message)
                trainer = self.trainer = self._make(self)
            if self.steps is not None:
                trainer.config.steps = int(self.steps)
            total = trainer.step_limit
            start = trainer.step
            self._set(phase="training", message="", step=start, start_step=start, total=total,
                      until_done=trainer.until_done, gaussians=len(trainer),
                      sizing=trainer.strategy.sizing, elapsed=0.0)
            threads = trainer.config.threads
            if self._thread is not None and threads == 0:  # beside a UI: leave it a core
                trainer.config.threads = ui_kernel_threads()
            try:
                if self._thread is not None and trainer.config.threads == 1:
                    # The kernels run on the training's own thread, beside the UI: it yields.
                    at_background_priority(lambda: self._train(trainer, total))
                else:
                    self._train(trainer, total)
            finally:
                trainer.config.threads = threads
            if self.after_training is not None:
                self.after_training(trainer)
            finished = trainer.step >= total or (trainer.until_done and trainer.converged)
            evaluation = None
            if finished and self.compact_after:
                self._set(phase="compacting", message="compacting")
                self.compaction = compact(trainer)
                self._set(gaussians=len(trainer), sh_degree=trainer.config.sh_degree)
            if finished and self.evaluate and trainer.dataset.test_indices:
                self._set(phase="evaluating", message="evaluating the held-out views")
                evaluation = trainer.evaluate()
            if self.checkpoint is not None and (finished or trainer.step != start):
                self._set(phase="saving", message="saving the checkpoint")
                self._save_checkpoint(trainer)
            self._publish(trainer, final=True)
            self._set(phase="done" if finished else "cancelled", message="",
                      evaluation=evaluation, eta=0.0 if finished else None)
        except JobCancelled:
            self._set(phase="cancelled", message="cancelled while preparing")
        except BaseException as error:  # reported to the caller, never lost on the thread
            self.error = error
            self.error_traceback = traceback.format_exc()
            if trainer is not None:
                try:
                    self._publish(trainer, final=True)
                except Exception:  # an inconsistent state: publish nothing
                    pass
            self._set(phase="failed", message=f"{type(error).__name__}: {error}")
        finally:
            self._done.set()

    def _wait_out_hold(self) -> bool:
        """Sleep until `hold`'s time is over (or a cancel); True if it slept."""
        slept = False
        while True:
            with self._lock:
                left = self._held_until - time.monotonic()
            if left <= 0 or self._cancel.wait(left):
                return slept
            slept = True

    def _train(self, trainer: Trainer, total: int) -> None:
        losses: deque = deque(maxlen=self._window.maxlen)
        psnrs: deque = deque(maxlen=self._window.maxlen)
        started = last = time.perf_counter()
        steps = trainer.run(total)
        while not self._cancel.is_set():
            if self._wait_out_hold():
                last = time.perf_counter()  # a held step's time is not the step's
            if self.before_step is not None:
                self.before_step(trainer)
            try:
                stats = next(steps)
            except StopIteration:
                break
            now = time.perf_counter()
            self._window.append(now - last)
            last = now
            losses.append(stats["loss"])
            psnrs.append(stats["psnr"])
            step = stats["step"]
            per_step = sum(self._window) / len(self._window)
            if self.snapshot_every and step % self.snapshot_every == 0 and step < total:
                self._publish(trainer)
            if (self.checkpoint is not None and self.checkpoint_every
                    and step % self.checkpoint_every == 0 and step < total):
                self._save_checkpoint(trainer)
            self._set(step=step, loss=sum(losses) / len(losses), psnr=sum(psnrs) / len(psnrs),
                      gaussians=stats["gaussians"], sizing=stats.get("sizing", ""),
                      gain_per_minute=trainer.gain_per_minute, sh_degree=stats["sh_degree"],
                      elapsed=now - started, seconds_per_step=per_step,
                      eta=per_step * (total - step) if len(self._window) >= 3 else None)


def ui_kernel_threads() -> int:
    """Kernel threads for training beside a UI: every core but one (at least one;
    `threads.kernel_threads`, the one rule)."""
    return kernel_threads(beside_ui=True, cores=cpu_count())


WAIT_STEP = 0.05  # seconds a blocking StagedJob sleeps when its steps wait on other work


class StagedJob:
    """Work that must stay on one thread (it touches Blender data), done in small steps:
    `steps` is a generator of (stage, fraction of that stage) or (stage, fraction, what the
    status line says instead of the stage's name), or None while it waits on work elsewhere (a
    process, a thread: `poll` then returns at once, `run` sleeps a little), whose return value
    becomes `result`;
    `stages` names them in order, for the overall fraction (`weights`: their shares). The same
    interface as `TrainingJob` (start, poll, run, cancel, join, progress), so one runner drives both:
    `poll(seconds)` advances it for about that long (from a UI timer), `run()` to the end.
    Cancelling closes the generator at the next poll (its `finally` blocks clean up)."""

    def __init__(self, steps: Generator[tuple[str, float], None, object],
                 stages: Sequence[str], *, weights: Sequence[float] | None = None,
                 on_progress: Callable[[Progress], None] | None = None) -> None:
        self._steps = steps
        self.stages = tuple(stages)
        # Each stage's share of the overall fraction (default: equal shares).
        shares = list(weights) if weights is not None else [1.0] * len(self.stages)
        total = sum(shares) or 1.0
        self._starts = [sum(shares[:k]) / total for k in range(len(shares))]
        self._shares = [share / total for share in shares]
        self.on_progress = on_progress
        self.result = None
        self.error: BaseException | None = None
        self.error_traceback = ""
        self.trainer = None
        self.final = None
        self._cancel = False
        self._done = False
        self._started = time.perf_counter()
        self._progress = Progress()

    def _set(self, **changes) -> None:
        self._progress = replace(self._progress, elapsed=time.perf_counter() - self._started,
                                 **changes)
        if self.on_progress is not None:
            self.on_progress(replace(self._progress))

    def start(self) -> "StagedJob":
        self._started = time.perf_counter()
        self._set(phase="working", message=self.stages[0] if self.stages else "")
        return self

    def poll(self, seconds: float = 0.0) -> None:
        """Advance for about `seconds` (at least one step); finish when the work ends."""
        deadline = time.perf_counter() + seconds
        while not self._done:
            if self._cancel:
                self._steps.close()
                self._end("cancelled")
                return
            try:
                step = next(self._steps)
            except StopIteration as finished:
                self.result = finished.value
                self._end("done")
                return
            except BaseException as error:  # reported to the caller by `error`
                self.error = error
                self.error_traceback = traceback.format_exc()
                self._end("failed", f"{type(error).__name__}: {error}")
                return
            if step is None:  # waiting on work elsewhere
                if seconds != float("inf"):
                    return  # the thread is the caller's until the next poll
                time.sleep(WAIT_STEP)  # blocking (`run`): wait a little
                continue
            stage, fraction, *detail = step
            index = self.stages.index(stage) if stage in self.stages else 0
            overall = (self._starts[index] + self._shares[index] * min(max(fraction, 0.0), 1.0)
                       if self.stages else 0.0)
            self._set(phase="working", message=detail[0] if detail else stage, prepared=overall)
            if time.perf_counter() >= deadline:
                return

    def _end(self, phase: str, message: str = "") -> None:
        self._done = True
        self._set(phase=phase, message=message,
                  prepared=1.0 if phase == "done" else self._progress.prepared)

    def run(self, *, raise_errors: bool = True) -> "StagedJob":
        self.start()
        self.poll(float("inf"))
        if self.error is not None and raise_errors:
            raise self.error
        return self

    def cancel(self) -> None:
        self._cancel = True

    @property
    def cancelled(self) -> bool:
        return self._cancel

    def join(self, timeout: float | None = None) -> bool:
        """No thread to wait for: a cancelled job is closed now."""
        if self._cancel and not self._done:
            self.poll()
        return self._done

    @property
    def done(self) -> bool:
        return self._done

    def progress(self) -> Progress:
        return replace(self._progress)

    def take_snapshot(self) -> None:
        return None


class ProgressPrinter:
    """Terminal lines for a job without a window (`blender --background`, the bpy wheel): one
    at every phase or stage change, else at most one every `interval` seconds."""

    def __init__(self, title: str, interval: float = 5.0,
                 write: Callable[[str], None] | None = None) -> None:
        self.title = title
        self.interval = float(interval)
        self.write = write or (lambda line: print(line, flush=True))
        self._key = None
        self._last = float("-inf")

    def __call__(self, p: Progress) -> None:
        key = (p.phase, p.message if p.phase == "working" else "")
        now = time.monotonic()
        if key != self._key or now - self._last >= self.interval:
            self._key, self._last = key, now
            self.write(status_line(p, self.title))
