"""How much of Blender's main thread Import Photos or Video takes: the operator's job driven as
its modal timer drives it in the UI (a poll every 0.25 s with a 0.1 s budget,
`blender/job_runner.py`), on the demo photos, in the project's bpy. Prints how long each poll
held the main thread (what a 10 ms UI timer would wait at most) during the reconstruction (a
child process) and during the import (Blender data, on the main thread). Numbers only.

    .venv/bin/python benchmarks/bench_reconstruct_ui.py [--photos examples/demo_colmap/images]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--photos", type=Path, default=ROOT / "examples" / "demo_colmap" / "images")
    parser.add_argument("--threads", type=int, default=1, help="the child's (the UI keeps a core)")
    args = parser.parse_args()
    import bpy

    import addon
    from addon.blender import job_runner
    from addon.blender.io import reconstruct
    from addon.core.jobs import StagedJob

    addon.register()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    out = Path(tempfile.mkdtemp(prefix="bench-reconstruct-ui-")) / "scene"
    steps = reconstruct.reconstruct_steps(args.photos, out, {"threads": args.threads},
                                          {"scene": bpy.context.scene})
    job = StagedJob(steps, reconstruct.STAGES, weights=reconstruct.WEIGHTS).start()
    held: dict[str, list[float]] = {stage: [] for stage in reconstruct.STAGES}
    started = time.perf_counter()
    while not job.done:
        time.sleep(job_runner.TIMER_STEP)
        before = time.perf_counter()
        job.poll(job_runner.STAGE_BUDGET)
        stage = "importing" if job.progress().message.startswith("importing") else \
            "reconstructing"
        held[stage].append(1000 * (time.perf_counter() - before))
    wall = time.perf_counter() - started
    assert job.error is None, job.error
    print(f"{args.photos}: {wall:.1f} s wall, child on {args.threads} thread(s)")
    print("| stage | polls | median ms | p95 ms | max ms | main-thread share |")
    print("| --- | ---: | ---: | ---: | ---: | ---: |")
    for stage, times in held.items():
        t = np.array(times or [0.0])
        share = t.sum() / 1000 / (len(times) * (job_runner.TIMER_STEP + t.mean() / 1000) or 1)
        print(f"| {stage} | {len(times)} | {np.median(t):.2f} | {np.percentile(t, 95):.2f} | "
              f"{t.max():.2f} | {100 * share:.1f} % |")


if __name__ == "__main__":
    main()
