"""Long jobs, Blender-free (`addon/core/jobs.py`): a `StagedJob` steps, finishes, fails and
cancels like a `TrainingJob`, and headless runs print one line per stage (and every few seconds),
never one per step."""

from __future__ import annotations

import sys

import pytest

from addon.core.jobs import Progress, ProgressPrinter, StagedJob, status_line

STAGES = ("load", "work", "write")


def _steps(log: list, fail_at: str | None = None):
    try:
        for stage in STAGES:
            for k in range(4):
                if stage == fail_at:
                    raise ValueError(f"{stage} broke")
                yield stage, (k + 1) / 4
        return "result"
    finally:
        log.append("cleaned up")


def test_staged_job_runs_to_its_result_with_overall_progress() -> None:
    seen: list[Progress] = []
    log: list = []
    job = StagedJob(_steps(log), STAGES, on_progress=seen.append).run()
    assert job.done and job.result == "result" and job.error is None and log == ["cleaned up"]
    assert job.progress().phase == "done" and job.progress().fraction == 1.0
    working = [p.fraction for p in seen if p.phase == "working"]
    assert working == sorted(working) and working[-1] == pytest.approx(1.0)
    assert [p.message for p in seen if p.phase == "working"][5] == "work"
    assert status_line(seen[5], "Converting") == "Converting: work (42 %)"


def test_staged_job_polls_cancels_and_fails_cleanly() -> None:
    log: list = []
    job = StagedJob(_steps(log), STAGES).start()
    job.poll()  # one step at a time (no time budget)
    assert not job.done and job.progress().message == "load"
    job.cancel()
    assert job.join() and job.done and job.result is None and log == ["cleaned up"]
    assert job.progress().phase == "cancelled"

    failing = StagedJob(_steps([], fail_at="write"), STAGES).run(raise_errors=False)
    assert failing.done and isinstance(failing.error, ValueError)
    assert failing.progress().phase == "failed" and "write broke" in failing.progress().message
    assert status_line(failing.progress(), "Converting") == \
        "Converting failed: ValueError: write broke"
    with pytest.raises(ValueError, match="load broke"):
        StagedJob(_steps([], fail_at="load"), STAGES).run()


def test_steps_that_wait_give_the_thread_back_and_weights_share_the_bar() -> None:
    """A step of None (the work is elsewhere, a child process) ends a poll at once, whatever its
    budget; `run` waits through it. Details replace the stage's name in the status line."""
    def waiting():
        yield "wait", 0.5, "half done elsewhere"
        for _ in range(3):
            yield None
        yield "finish", 1.0
        return "ok"

    job = StagedJob(waiting(), ("wait", "finish"), weights=(3, 1)).start()
    job.poll(10.0)  # returns at the first None, not after 10 s
    assert job.progress().message == "half done elsewhere"
    assert job.progress().fraction == pytest.approx(0.375)
    for _ in range(2):  # the other two waits
        job.poll(10.0)
    assert not job.done
    job.poll(10.0)
    assert job.done and job.result == "ok"
    assert StagedJob(waiting(), ("wait", "finish")).run().result == "ok"


def test_printer_writes_a_line_per_stage_not_per_step() -> None:
    lines: list[str] = []
    printer = ProgressPrinter("Converting", interval=3600.0, write=lines.append)
    StagedJob(_steps([]), STAGES, on_progress=printer).run()
    assert lines == ["Converting: load (0 %)", "Converting: work (42 %)",
                     "Converting: write (75 %)", "Converting: done"]
    training: list[str] = []
    printer = ProgressPrinter("Training", interval=3600.0, write=training.append)
    for step in range(1, 500):
        printer(Progress(phase="training", step=step, total=500, gaussians=10))
    printer(Progress(phase="done", step=500, total=500, gaussians=10))
    assert len(training) == 2 and training[0].startswith("Training step 1 of 500")
    every = ProgressPrinter("Training", interval=0.0, write=training.append)
    every(Progress(phase="training", step=1, total=5))
    every(Progress(phase="training", step=2, total=5))
    assert len(training) == 4  # with no interval, every call


def test_a_training_job_on_a_worker_leaves_the_ui_a_core(monkeypatch) -> None:
    from pathlib import Path

    from addon.core import jobs
    from addon.core.colmap import read_colmap
    from addon.core.jobs import TrainingJob
    from addon.core.train.dataset import ColmapDataset
    from addon.core.train.trainer import Trainer, TrainConfig

    demo = Path(__file__).resolve().parents[3] / "examples" / "demo_colmap"
    dataset = ColmapDataset(read_colmap(demo), downscale=8)
    monkeypatch.setattr(jobs, "cpu_count", lambda: 4)
    for start, want in ((True, 3), (False, 0)):  # a worker beside a UI; the calling thread
        trainer = Trainer(dataset, TrainConfig(steps=3, sh_degree=0, threads=0))
        seen = []
        job = TrainingJob(trainer, evaluate=False,
                          on_progress=lambda p: seen.append(trainer.config.threads))
        if start:
            job.start().join()
        else:
            job.run()
        assert job.done and job.error is None and trainer.step == 3
        assert set(seen[1:-1]) == {want}  # while it trained
        assert trainer.config.threads == 0  # as configured afterwards (checkpoints say so)
    monkeypatch.setattr(jobs, "cpu_count", lambda: 1)
    assert jobs.ui_kernel_threads() == 1


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread nice: Linux")
def test_a_training_whose_kernels_share_the_uis_cores_yields_to_it(monkeypatch) -> None:
    """On 2 cores the kernels run on the training's own thread, beside the UI's redraws: its
    steps run at a lowered priority; what follows (compaction, evaluation, on all cores and so
    through the native thread pool) does not, so the pool never inherits it."""
    import os
    import threading
    from pathlib import Path

    from addon.core import jobs
    from addon.core.colmap import read_colmap
    from addon.core.jobs import TrainingJob
    from addon.core.priority import BACKGROUND_NICE
    from addon.core.train.dataset import ColmapDataset
    from addon.core.train.trainer import Trainer, TrainConfig

    def nice() -> int:
        return os.getpriority(os.PRIO_PROCESS, threading.get_native_id())

    demo = Path(__file__).resolve().parents[3] / "examples" / "demo_colmap"
    dataset = ColmapDataset(read_colmap(demo), downscale=8)
    monkeypatch.setattr(jobs, "cpu_count", lambda: 2)
    for start in (True, False):
        trainer = Trainer(dataset, TrainConfig(steps=3, sh_degree=0, threads=0))
        seen: dict[str, set[int]] = {}
        job = TrainingJob(trainer, evaluate=True, on_progress=lambda p: seen.setdefault(
            "steps" if p.phase == "training" and p.step else p.phase, set()).add(nice()))
        (job.start().join() if start else job.run())
        assert job.done and job.error is None
        base = nice()  # this thread's, which the worker inherited
        assert seen["steps"] == ({max(base, BACKGROUND_NICE)} if start else {base})
        assert seen["evaluating"] == {base}


def test_a_held_training_takes_no_step_until_its_time() -> None:
    """`hold`: the UI's redraws of a new object have the cores to themselves (`job_runner`,
    issue 36): after the step that runs, none starts before the time is over, and a cancel ends
    the wait at once."""
    import time
    from pathlib import Path

    from addon.core.colmap import read_colmap
    from addon.core.jobs import TrainingJob
    from addon.core.train.dataset import ColmapDataset
    from addon.core.train.trainer import Trainer, TrainConfig

    demo = Path(__file__).resolve().parents[3] / "examples" / "demo_colmap"
    dataset = ColmapDataset(read_colmap(demo), downscale=8)
    trainer = Trainer(dataset, TrainConfig(steps=100_000, sh_degree=0, threads=1))
    job = TrainingJob(trainer, evaluate=False).start()

    def wait_for(condition, seconds: float = 20.0) -> float:
        deadline = time.monotonic() + seconds
        while not condition():
            assert time.monotonic() < deadline
            time.sleep(0.005)
        return time.monotonic()

    wait_for(lambda: trainer.step >= 3)
    held = time.monotonic()
    job.hold(0.6)
    time.sleep(0.15)  # the step that was running ends
    step = trainer.step
    time.sleep(0.3)
    assert trainer.step == step  # none in the held time
    resumed = wait_for(lambda: trainer.step > step)
    assert resumed >= held + 0.6
    job.hold(60.0)
    time.sleep(0.05)
    job.cancel()
    assert job.join(10.0)  # long before the hold's 60 s
    assert job.progress().phase == "cancelled"
