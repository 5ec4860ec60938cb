"""Splat scenes rendered by a real Flamenco 3 farm, frame for frame as at home.

    sudo .venv/bin/python scripts/test_farm.py [--suite sid] [--keep]

Builds Flamenco's manager and worker from ../shared/farm (once; cached under
~/.cache/splat-farm), starts a manager and two workers on 127.0.0.1 with a shared-storage folder
under `$(root.sh SUITE)/io/farm/`, each worker running the suite's real Blender (default: Debian's
5.2) through scripts/farm/blender_in_root.sh, with the extension zip installed for the worker's
user as docs/guide/render_farms.md tells farm users (`blender --command extension install-file`).
Jobs are submitted as Flamenco's add-on submits them ("Simple Blender Render" through the REST
API, with the settings its job type evaluates in the artist's Blender), and every frame is checked:

- anim: 6 frames of splats with a cube in front, a plane behind and a moving camera. Every farm
  frame equals the artist's `blender -b -a` frame within 1/255, and differs from the same frame
  rendered without splats. Injected: worker w1 is killed (SIGKILL, with its Blender) in the middle
  of a task and restarted, as a service manager would; the job must still complete.
- rig: the anim splats parented to a two-bone armature (vertex groups weighted by height), the
  upper bone turning over the 6 frames, a still camera: every farm frame equals the artist's
  `-a` frame within 1/255, the frames differ from each other (the rig moves), and the posed
  frames differ from the same frames rendered with the Gaussians' shapes and SH left at rest
  (the centres alone following the bones): the farm bends the splats themselves.
- sequence: a splat sequence (one file per frame) in a `frames/` folder beside the .blend in
  shared storage, referenced relative to the .blend; each farm frame equals the local one and
  every frame differs from the others. Injected: the same job with frame 4's file missing
  must fail that frame's task with a message naming it, and write no frame 4.
- no extension / broken native module: a worker without the extension, and one whose native
  module cannot load, must fail their tasks with a message and write no frame; the one
  without the extension before it renders the scene's meshes.
- saved scene (before the farm starts, `blender -b -y FILE -f 1` as a worker runs it): the splat
  object hidden, disabled in viewports or deleted, the helper data taken away in turn
  (tests/farm/damage.py), and the add-on absent (--factory-startup): never a crash, each frame
  equal to the local one with or without splats as the case says, or a loud failure.
- 5.3 splats: Blender 5.3's own splat point cloud (made by its PLY importer, rendered by the
  add-on) in the `anim` scene, on a worker whose Blender is the official `bpy` 5.3.0 module
  (`../shared/real-blender/bpy313.sh`; only the module, not the executable, runs here) behind
  scripts/farm/bpy_blender.py, which carries out Blender's command line: each farm frame equals
  the artist's `-a` frame (same module) and differs from it without the splats; a 5.3 worker
  without the extension renders them with Blender's own renderer (the file is Blender's: its
  tasks complete, no frame without splats).

Ends with one line per job and exits non-zero on a missing frame, a difference over 1/255, or an
injected failure that was not reported. Bounded waits everywhere; every process started here is
stopped at the end (also on errors); the manager and workers listen on 127.0.0.1 only.
"""

from __future__ import annotations

import argparse
import json
import signal
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(REPO), str(REPO / "tests"), str(REPO / "scripts" / "farm")]

import flamenco  # noqa: E402
from scenes import random_gaussians  # noqa: E402
from standard_view import read_png  # noqa: E402

FRAMES = range(1, 7)
MISSING_FRAME = 4
start_time = time.monotonic()


def log(message: str) -> None:
    print(f"test_farm [{time.monotonic() - start_time:6.1f} s] {message}", flush=True)


class Blender:
    """The suite's real Blender through the worker wrapper, as a given user (HOME); `command`:
    the Blender inside `root` when it is not `blender` (SPLAT_FARM_BLENDER)."""

    def __init__(self, wrapper: Path, root: Path, farm: Path, command: str = "") -> None:
        self.wrapper, self.root, self.farm, self.command = wrapper, root, farm, command

    def env(self, home: Path) -> dict:
        return {"SPLAT_FARM_ROOT": str(self.root), "SPLAT_FARM_DIR": str(self.farm),
                "SPLAT_FARM_HOME": str(home),
                **({"SPLAT_FARM_BLENDER": self.command} if self.command else {})}

    def run(self, home: Path, *args: str, timeout: float = 600, check: bool = True):
        home.mkdir(parents=True, exist_ok=True)
        env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), **self.env(home)}
        result = subprocess.run([str(self.wrapper), *args], env=env, capture_output=True,
                                text=True, timeout=timeout)
        if check and result.returncode != 0:
            raise RuntimeError(f"blender {' '.join(args)} exited {result.returncode}:\n"
                               f"{result.stdout[-3000:]}\n{result.stderr[-2000:]}")
        return result


def install_extension(blender: Blender, home: Path, zip_path: Path) -> None:
    """What docs/guide/render_farms.md tells farm users to run, as the worker's user."""
    result = blender.run(home, "--command", "extension", "install-file", "-r", "user_default",
                         "-e", str(zip_path))
    if "Installed" not in result.stdout + result.stderr and \
            "Reinstalled" not in result.stdout + result.stderr:
        raise RuntimeError(f"extension install-file said:\n{result.stdout}\n{result.stderr}")


def break_native_module(home: Path) -> Path:
    """A worker whose native module cannot load (a wrong build copied over it)."""
    modules = sorted(home.glob(".config/blender/*/extensions/**/splatcore*.so"))
    if not modules:
        raise RuntimeError(f"no splatcore module under {home}")
    for module in modules:
        module.write_bytes(b"not a shared object\n")
    return modules[0]


def frames_in(folder: Path) -> dict[int, Path]:
    found = {}
    for path in folder.glob("*.png"):
        match = re.fullmatch(r"(\d+)", path.stem)
        if match:
            found[int(match.group(1))] = path
    return found


def worst_difference(a: Path, b: Path) -> int:
    """The largest difference of two frames, 0-255; 255 when either is no image (a worker
    killed while writing leaves an empty file: a failed frame, not a crash of this test)."""
    try:
        x, y = read_png(a), read_png(b)
    except OSError as error:
        log(f"unreadable frame: {error}")
        return 255
    if x.shape != y.shape:
        return 255
    return int(np.abs(x - y).max())


class Results:
    def __init__(self) -> None:
        self.lines: list[str] = []
        self.failed = False

    def add(self, job: str, ok: bool | None, frames: str, worst: str, injected: str,
            detail: str = ""):
        """One job's line; `ok` None: not run (says "skip", neither passed nor failed)."""
        self.failed |= ok is False
        status = "skip" if ok is None else "ok" if ok else "FAIL"
        self.lines.append(f"{job:<14} {status:<4}  frames {frames:<5}  "
                          f"worst {worst:<7}  injected {injected}"
                          + (f"  ({detail})" if detail else ""))


def make_inputs(farm: Path) -> dict:
    """Splats for the animation, and a 6-frame sequence (each frame its own splats: a cluster
    that moves from left to right)."""
    from addon.core.formats.sequence import save_sequence
    inputs = farm / "inputs"
    inputs.mkdir(parents=True, exist_ok=True)
    g = random_gaussians(np.random.default_rng(20261127), 400, 1, radius=1.0, stray=0.0)
    np.savez(inputs / "splats.npz", **g.arrays())
    from addon.core.formats import ply
    ply.save(g, inputs / "splats.ply")   # the same splats, for Blender 5.3's own PLY importer
    rng = np.random.default_rng(30)
    frames = [(n, random_gaussians(rng, 300, 1, centre=(-1.2 + 0.45 * n, 0.0, 0.0), radius=0.6,
                                   stray=0.0)) for n in FRAMES]
    seq_dir = farm / "storage" / "projects" / "sequence" / "frames"
    seq_dir.mkdir(parents=True, exist_ok=True)
    save_sequence(frames, seq_dir / "walk_####.ply")
    return {"splats": inputs / "splats.npz", "splats_ply": inputs / "splats.ply",
            "sequence": seq_dir / "walk_####.ply"}


def build_scene(blender: Blender, artist: Path, kind: str, source: Path, out: Path) -> dict:
    scripts = blender.farm / "scripts"   # inside the root too (the farm folder is bound there)
    scripts.mkdir(exist_ok=True)
    for script in ("tests/farm/farm_scene.py", "tests/real_blender/scene_kit.py",
                   "tests/farm/damage.py", "scripts/farm/bpy_blender.py"):
        shutil.copy2(REPO / script, scripts)
    result = blender.run(artist, "-b", "--python", str(scripts / "farm_scene.py"), "--",
                         kind, str(source), str(out))
    line = next(line for line in result.stdout.splitlines() if line.startswith("FARM_SETTINGS "))
    return json.loads(line.split(" ", 1)[1])


def job_settings(evaluated: dict, blendfile: Path, output_root: Path, name: str) -> dict:
    """The job's settings as Flamenco's add-on sends them: what the job type's `eval`s gave in
    the artist's Blender, the .blend's path in shared storage, and the render output path its
    `eval` builds (root / last 0 parts of the .blend's folder / job name / {timestamp} / ######)."""
    return {**evaluated, "blendfile": str(blendfile), "chunk_size": 1,
            "render_output_root": str(output_root), "add_path_components": 0,
            "render_output_path": str(output_root / name / "{timestamp}" / "######")}


def job_output(job: dict) -> Path:
    return Path(job["settings"]["render_output_path"]).parent


def task_summary(farm: flamenco.Farm, job_id: str) -> tuple[dict, dict]:
    """{frame: status} and {frame: task record} of a job's render tasks."""
    statuses, records = {}, {}
    for task in farm.api.tasks(job_id):
        match = re.fullmatch(r"render-(\d+)", task["name"])
        if match:
            statuses[int(match.group(1))] = task["status"]
            records[int(match.group(1))] = task
    return statuses, records


def compare_frames(written: dict, local: dict, frames) -> tuple[list[int], int]:
    missing = [f for f in frames if f not in written or f not in local]
    worst = max((worst_difference(written[f], local[f]) for f in frames
                 if f in written and f in local), default=0)
    return missing, worst


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--suite", default="sid")
    parser.add_argument("--keep", action="store_true",
                        help="leave the farm folder for a look (it stays after a failure)")
    args = parser.parse_args()
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))   # stop the farm on the way out
    shared = REPO.parent / "shared"
    rb = shared / "real-blender"
    root = Path(subprocess.run([str(rb / "root.sh"), args.suite], capture_output=True,
                               text=True, check=True).stdout.strip())
    if not (root / "usr/bin/blender").exists():
        subprocess.run([str(rb / "setup.sh"), args.suite], check=True)
    farm_dir = root / "io" / "farm"
    shutil.rmtree(farm_dir, ignore_errors=True)
    storage = farm_dir / "storage"
    (storage / "render").mkdir(parents=True)
    homes = farm_dir / "homes"
    wrapper = REPO / "scripts/farm/blender_in_root.sh"
    blender = Blender(wrapper, root, farm_dir)
    results = Results()
    timings: dict[str, float] = {}

    bin_dir, build_s = flamenco.build(shared / "farm", Path.home() / ".cache/splat-farm", log)
    log(f"Flamenco binaries in {bin_dir} (built in {build_s:.0f} s)" if build_s else
        f"Flamenco binaries in {bin_dir} (cached)")
    subprocess.run([str(REPO / ".venv/bin/python"), "scripts/build_extension.py", "--platform",
                    "linux-x64"], cwd=REPO, check=True, stdout=subprocess.DEVNULL)
    zip_path = max((REPO / "dist").glob("gaussian_splatting-*-linux_x64.zip"),
                   key=lambda p: p.stat().st_mtime)
    farm_zip = farm_dir / zip_path.name
    shutil.copy2(zip_path, farm_zip)
    for user in ("artist", "w1", "w2", "broken"):
        install_extension(blender, homes / user, farm_zip)
    broken_module = break_native_module(homes / "broken")
    log(f"extension {zip_path.name} installed for artist, w1, w2, broken "
        f"(broken: {broken_module.name} overwritten); noext: not installed")
    (homes / "noext").mkdir(parents=True, exist_ok=True)

    inputs = make_inputs(farm_dir)
    anim_blend = storage / "projects" / "anim" / "anim.blend"
    seq_blend = storage / "projects" / "sequence" / "sequence.blend"
    rig_blend = storage / "projects" / "rig" / "rig.blend"
    anim_eval = build_scene(blender, homes / "artist", "anim", inputs["splats"], anim_blend)
    rig_eval = build_scene(blender, homes / "artist", "rig", inputs["splats"], rig_blend)
    seq_eval = build_scene(blender, homes / "artist", "sequence", inputs["sequence"], seq_blend)
    # The missing-frame case: the same project with frame 4's file not delivered.
    missing_dir = storage / "projects" / "sequence_missing"
    shutil.copytree(seq_blend.parent, missing_dir)
    (missing_dir / "frames" / f"walk_{MISSING_FRAME:04d}.ply").unlink()

    # The artist's own renders: `blender -b FILE -a`, the farm's reference.
    local = farm_dir / "local"
    t0, c0 = time.monotonic(), os.times()
    blender.run(homes / "artist", "-b", str(anim_blend), "-o", str(local / "anim" / "######"), "-a")
    c1 = os.times()
    timings["local_anim_s"] = time.monotonic() - t0
    timings["local_anim_cpu_s"] = (c1.children_user + c1.children_system
                                   - c0.children_user - c0.children_system)
    blender.run(homes / "artist", "-b", str(anim_blend), "--python-expr",
                "import bpy; bpy.context.scene.splat_render.enabled = False",
                "-o", str(local / "anim_nosplats" / "######"), "-a")
    t0 = time.monotonic()
    blender.run(homes / "artist", "-b", str(rig_blend), "-o", str(local / "rig" / "######"), "-a")
    timings["local_rig_s"] = time.monotonic() - t0
    blender.run(homes / "artist", "-b", str(rig_blend), "--python-expr", RIG_AT_REST,
                "-o", str(local / "rig_at_rest" / "######"), "-a")
    t0 = time.monotonic()
    blender.run(homes / "artist", "-b", str(seq_blend), "-o", str(local / "sequence" / "######"),
                "-a")
    timings["local_sequence_s"] = time.monotonic() - t0
    log(f"local renders done (anim -a: {timings['local_anim_s']:.1f} s wall, "
        f"{timings['local_anim_cpu_s']:.1f} s CPU)")

    run_damage(blender, homes, anim_blend, local, results)

    farm = flamenco.Farm(bin_dir, farm_dir / "flamenco", storage, wrapper, log)
    try:
        farm.start_manager()
        for name in ("w1", "w2"):
            farm.start_worker(name, blender.env(homes / name))
        log(f"manager on {farm.api.url}, workers w1 and w2 awake")
        run_anim(farm, blender, homes, anim_blend, anim_eval, storage, local, results, timings)
        run_rig(farm, rig_blend, rig_eval, storage, local, results, timings)
        run_sequence(farm, seq_blend, seq_eval, storage, local, results, timings)
        run_missing_frame(farm, missing_dir / "sequence.blend", seq_eval, storage, results)
        farm.stop_worker("w1")
        farm.stop_worker("w2")
        run_bad_worker(farm, blender, homes, "noext", anim_blend, anim_eval, storage, results,
                       r"Engine 'SPLAT_GAUSSIANS' not available for scene '[^']*Gaussian Splatting extension",
                       before_the_meshes=True)
        run_bad_worker(farm, blender, homes, "broken", anim_blend, anim_eval, storage, results,
                       r"splatcore")
        run_splats53(farm, rb, wrapper, farm_dir, homes, inputs["splats_ply"], storage, zip_path,
                     results, timings)
    finally:
        farm.stop()

    print()
    print(f"farm test ({args.suite}), {time.monotonic() - start_time:.0f} s:")
    for line in results.lines:
        print(line)
    for job in ("sequence", "anim", "rig"):
        if f"farm_{job}_s" in timings:
            print(f"{job}: frames per minute: farm (2 workers) "
                  f"{60 * len(FRAMES) / timings[f'farm_{job}_s']:.1f}, local -a "
                  f"{60 * len(FRAMES) / timings[f'local_{job}_s']:.1f}; submission to first "
                  f"frame {timings.get(f'{job}_first_frame_s', float('nan')):.1f} s"
                  + ("  (a worker killed and restarted during it)" if job == "anim" else ""))
    if "farm_splats53_s" in timings:
        print(f"splats53: frames per minute: farm (1 bpy {BPY53} worker) "
              f"{60 * len(FRAMES) / timings['farm_splats53_s']:.1f}, local -a "
              f"{60 * len(FRAMES) / timings['local_splats53_s']:.1f}")
    if args.keep or results.failed:
        print(f"the farm's files (logs in flamenco/, frames in storage/render/): {farm_dir}")
    else:
        shutil.rmtree(farm_dir, ignore_errors=True)   # ~1.4 GB: four installed extensions
    return 1 if results.failed else 0


# (case, with the extension?, what the render must give: "splats" (= the local frame 1),
# "meshes" (= the local frame 1 without splats), "empty" (every pixel 0) or "fails" (exit 1,
# no file, a message))
DAMAGE = [("hide-render", True, "meshes"), ("hide-viewport", True, "splats"),
          ("delete", True, "meshes"), ("empty-objects", True, "splats"),
          ("helper-renamed", True, "splats"), ("node-deleted", True, "splats"),
          ("node-renamed", True, "splats"), ("camera-cleared", True, "splats"),
          ("helper-deleted", True, "fails"), ("helper-deleted, saved", True, "splats"),
          ("compositing-off", True, "splats"),
          ("nothing", False, "fails"), ("hide-render", False, "fails"), ("delete", False, "fails"),
          # a script turned the compositor off: the view layers, saved off, render nothing
          ("compositing-off", False, "empty"),
          ("compositing-off, saved", False, "fails")]   # saved by the add-on: compositing on


def run_damage(blender, homes, blend, local, results) -> None:
    """The saved animation rendered (`-f 1`, as a worker renders it) after each thing a user or
    a script takes away, with the extension and without it (--factory-startup): never a crash,
    never a frame without what it should show."""
    out = blender.farm / "damage"
    version = re.search(r"Blender (\d+)\.(\d+)", blender.run(homes / "artist", "--version").stdout)
    version = (int(version.group(1)), int(version.group(2))) if version else (0, 0)
    expected = {"splats": frames_in(local / "anim")[1],
                "meshes": frames_in(local / "anim_nosplats")[1]}
    crashes, wrong, worst = [], [], 0
    for case, with_addon, want in DAMAGE:
        label = case + ("" if with_addon else " (no add-on)")
        if case == "helper-deleted" and version < (5, 1):
            want = "splats"   # up to 5.0 the render itself makes the helper scene again
        shutil.rmtree(out, ignore_errors=True)
        args = ["-b"] + ([] if with_addon else ["--factory-startup"]) + [
            "-y", str(blend), "-o", str(out / "######"), "--python",
            str(blender.farm / "scripts" / "damage.py"), "-f", "1", "--", case]
        if case.endswith(", saved"):   # damaged and saved by one process, rendered by another
            damaged = out.parent / "damaged.blend"
            blender.run(homes / "artist", "-b", "-y", str(blend), "--python",
                        str(blender.farm / "scripts" / "damage.py"), "--python-expr",
                        f"import bpy; bpy.ops.wm.save_as_mainfile(filepath={str(damaged)!r})",
                        "--", case.split(",")[0])
            args = ["-b"] + ([] if with_addon else ["--factory-startup"]) + [
                "-y", str(damaged), "-o", str(out / "######"), "-f", "1"]
        result = blender.run(homes / "artist", *args, check=False)
        written = frames_in(out)
        if result.returncode < 0 or result.returncode > 128:
            crashes.append(f"{label}: exit {result.returncode}")
            continue
        if want == "fails":
            text = result.stdout + result.stderr
            said = re.search(r"(Gaussian splats: ERROR: .*"
                             r"|Engine 'SPLAT_GAUSSIANS' not available.*)", text)
            if result.returncode == 0 or written or not said:
                wrong.append(f"{label}: exit {result.returncode}, {len(written)} files, "
                             f"{'a message' if said else 'no message'}")
            continue
        if result.returncode != 0 or 1 not in written:
            wrong.append(f"{label}: exit {result.returncode}, no frame")
            continue
        difference = (int(read_png(written[1]).max()) if want == "empty"
                      else worst_difference(written[1], expected[want]))
        worst = max(worst, difference)
        if difference > 1:
            wrong.append(f"{label}: {difference}/255 from the {want} frame")
    ok = not crashes and not wrong
    results.add("saved scene", ok, f"{len(DAMAGE)}", f"{worst}/255",
                f"{len(DAMAGE)} (hidden/deleted splats, helpers taken away, no add-on); "
                f"crashes {len(crashes)}, wrong {len(wrong)}",
                "; ".join(crashes + wrong))
    log(f"saved-scene cases done: crashes {crashes or 'none'}, wrong {wrong or 'none'}")


def run_anim(farm, blender, homes, blend, evaluated, storage, local, results, timings) -> None:
    """Job (a), with worker w1 killed in the middle of a task and restarted."""
    name = "anim"
    submitted = time.monotonic()
    job = farm.api.submit(name, job_settings(evaluated, blend, storage / "render", name))
    killed: list[str] = []
    first: list[float] = []

    def on_poll(job_record, tasks):
        out = job_output(job_record)
        if not first and frames_in(out):
            first.append(time.monotonic() - submitted)
        if killed or not _blender_running(farm, "w1"):
            return
        active = [farm.api.task(t["id"]) for t in tasks if t["status"] == "active"]
        mine = [t for t in active if (t.get("worker") or {}).get("name") == "w1"]
        if not mine:
            return
        time.sleep(1.0)   # inside the render: Blender has started on the file
        farm.kill("w1")
        killed.append(mine[0]["name"])
        log(f"injected: worker w1 killed (with its Blender) during {mine[0]['name']}")
        farm.start_worker("w1", blender.env(homes / "w1"))
        log("worker w1 restarted, as a service manager restarts it")

    record, tasks = farm.wait_job(job["id"], timeout=480, on_poll=on_poll)
    timings["farm_anim_s"] = time.monotonic() - submitted
    if first:
        timings["anim_first_frame_s"] = first[0]
    written = frames_in(job_output(record))
    missing, worst = compare_frames(written, frames_in(local / "anim"), FRAMES)
    plain = frames_in(local / "anim_nosplats")
    without_splats = [f for f in FRAMES if f in written and f in plain
                      and worst_difference(written[f], plain[f]) <= 1]
    ok = (_render_tasks_completed(tasks) and not missing and worst <= 1 and bool(killed)
          and not without_splats)
    detail = f"render tasks {_statuses(tasks)}, {timings['farm_anim_s']:.0f} s"
    if without_splats:
        detail += f"; frames {without_splats} have no splats"
    if missing:
        detail += f"; frames {missing} missing"
    results.add(name, ok, f"{len(written)}/{len(FRAMES)}", f"{worst}/255",
                f"1 (w1 killed in {killed[0]}; job completed)" if killed else "0 (kill not done)",
                detail)


# Run before `-a`: the splat object's Gaussians keep their rest shapes and SH, only their
# centres follow the bones (how the add-on read a deformed object before issue 35).
RIG_AT_REST = ("import importlib; importlib.import_module('bl_ext.user_default.gaussian_splatting"
               ".blender.sources.deformed').Deformable.rest_data = lambda self: None")


def _farm_frames(farm, blend, evaluated, storage, local, name, timings):
    """Submit job `name` (w1 and w2), wait for it, and hold its frames against the local ones
    of the same name: (tasks, frames written, frames missing, worst difference, pairs of
    frames the same)."""
    submitted = time.monotonic()
    job = farm.api.submit(name, job_settings(evaluated, blend, storage / "render", name))
    first: list[float] = []

    def on_poll(job_record, _tasks):
        if not first and frames_in(job_output(job_record)):
            first.append(time.monotonic() - submitted)

    record, tasks = farm.wait_job(job["id"], timeout=300, on_poll=on_poll)
    timings[f"farm_{name}_s"] = time.monotonic() - submitted
    timings[f"{name}_first_frame_s"] = first[0] if first else float("nan")
    written = frames_in(job_output(record))
    missing, worst = compare_frames(written, frames_in(local / name), FRAMES)
    same = [(a, b) for a in FRAMES for b in FRAMES if a < b and a in written and b in written
            and worst_difference(written[a], written[b]) <= 1]
    return tasks, written, missing, worst, same


def run_rig(farm, blend, evaluated, storage, local, results, timings) -> None:
    """The armature-deformed splats on the farm (w1 and w2), frame for frame as locally."""
    name = "rig"
    tasks, written, missing, worst, same = _farm_frames(farm, blend, evaluated, storage, local,
                                                        name, timings)
    at_rest = frames_in(local / "rig_at_rest")
    bent = {f: worst_difference(written[f], at_rest[f]) for f in FRAMES
            if f != FRAMES[0] and f in written and f in at_rest}
    unbent = [f for f, difference in bent.items() if difference <= 1]
    ok = (_render_tasks_completed(tasks) and not missing and worst <= 1 and not same
          and len(bent) == len(FRAMES) - 1 and not unbent)
    detail = (f"render tasks {_statuses(tasks)}, {timings['farm_rig_s']:.0f} s; against the "
              f"shapes left at rest: frames 2-{FRAMES[-1]} differ by up to "
              f"{max(bent.values(), default=0)}/255"
              + (f"; frames {unbent} as at rest" if unbent else "")
              + (f"; identical frames {same}" if same else "")
              + (f"; frames {missing} missing" if missing else ""))
    results.add(name, ok, f"{len(written)}/{len(FRAMES)}", f"{worst}/255", "0", detail)


def _render_tasks(tasks) -> list[dict]:
    return [t for t in tasks if t["name"].startswith("render-")]


def _render_tasks_completed(tasks) -> bool:
    return bool(_render_tasks(tasks)) and all(t["status"] == "completed"
                                              for t in _render_tasks(tasks))


def _statuses(tasks) -> str:
    counts: dict[str, int] = {}
    for task in _render_tasks(tasks):
        counts[task["status"]] = counts.get(task["status"], 0) + 1
    return " ".join(f"{n} {s}" for s, n in sorted(counts.items()))


def _blender_running(farm, worker: str) -> bool:
    """Whether the worker has a Blender child (the task really is rendering). The worker is a
    Go program: any of its threads may have started it, so every process's parent is read."""
    process = farm.processes.get(worker)
    if process is None:
        return False
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
        except OSError:
            continue
        name = text[text.index("(") + 1:text.rindex(")")]
        parent = int(text[text.rindex(")") + 2:].split()[1])
        if parent == process.pid and name == "blender":
            return True
    return False


def run_sequence(farm, blend, evaluated, storage, local, results, timings) -> None:
    name = "sequence"
    tasks, written, missing, worst, same = _farm_frames(farm, blend, evaluated, storage, local,
                                                        name, timings)
    ok = _render_tasks_completed(tasks) and not missing and worst <= 1 and not same
    detail = f"render tasks {_statuses(tasks)}" + (f"; identical frames {same}" if same else "") + \
        (f"; frames {missing} missing" if missing else "")
    results.add(name, ok, f"{len(written)}/{len(FRAMES)}", f"{worst}/255", "0", detail)


def run_missing_frame(farm, blend, evaluated, storage, results) -> None:
    name = "sequence-gap"
    job = farm.api.submit(name, job_settings(evaluated, blend, storage / "render", name))
    record, _ = farm.wait_job(job["id"], timeout=300)
    written = frames_in(job_output(record))
    statuses, tasks = task_summary(farm, job["id"])
    task = tasks.get(MISSING_FRAME)
    message = ""
    if task is not None:
        text = farm.api.task_log(task["id"])
        found = re.search(rf".*walk_{MISSING_FRAME:04d}.*", text)
        message = found.group(0).strip() if found else ""
    ok = (statuses.get(MISSING_FRAME) == "failed" and MISSING_FRAME not in written
          and bool(message))
    results.add(name, ok, f"{len(written)}/{len(FRAMES)}", "-",
                f"1 (frame {MISSING_FRAME} file missing: task {statuses.get(MISSING_FRAME)})",
                f"job {record['status']}; log: {message[:110]}")


BPY53 = "5.3.0"


def run_splats53(farm, rb, wrapper, farm_dir, homes, ply_path, storage, zip_path, results,
                 timings) -> None:
    """Blender 5.3's own splats on a 5.3 worker (the official bpy module behind
    scripts/farm/bpy_blender.py), then a 5.3 worker without the extension."""
    name = "5.3 splats"
    built = subprocess.run([str(rb / "bpy313.sh"), BPY53], capture_output=True, text=True)
    if built.returncode != 0:
        results.add(name, False, "-", "-", "-", f"bpy {BPY53} could not be set up: "
                    f"{(built.stdout + built.stderr).strip()[-300:]}")
        return
    root = Path(subprocess.run([str(rb / "root.sh"), "py313"], capture_output=True, text=True,
                               check=True).stdout.strip())
    blender = Blender(wrapper, root, farm_dir, f"/opt/bpy-{BPY53}/bin/python "
                      f"{farm_dir / 'scripts' / 'bpy_blender.py'}")
    for user in ("artist53", "w53"):
        install_extension(blender, homes / user, farm_dir / zip_path.name)
    (homes / "noext53").mkdir(parents=True, exist_ok=True)
    blend = storage / "projects" / "splats53" / "splats53.blend"
    evaluated = build_scene(blender, homes / "artist53", "splats53", ply_path, blend)
    local = farm_dir / "local"
    t0 = time.monotonic()
    blender.run(homes / "artist53", "-b", str(blend), "-o", str(local / "splats53" / "######"),
                "-a")
    timings["local_splats53_s"] = time.monotonic() - t0
    blender.run(homes / "artist53", "-b", str(blend), "--python-expr",
                "import bpy; [setattr(o, 'hide_render', True) for o in bpy.data.objects "
                "if o.type == 'POINTCLOUD']", "-o", str(local / "splats53_hidden" / "######"),
                "-a")
    log(f"bpy {BPY53}: extension installed for artist53 and w53, scene built, local renders done")

    farm.start_worker("w53", blender.env(homes / "w53"))
    submitted = time.monotonic()
    job = farm.api.submit("splats53", job_settings(evaluated, blend, storage / "render",
                                                   "splats53"))
    record, tasks = farm.wait_job(job["id"], timeout=300)
    timings["farm_splats53_s"] = time.monotonic() - submitted
    farm.stop_worker("w53")
    written = frames_in(job_output(record))
    missing, worst = compare_frames(written, frames_in(local / "splats53"), FRAMES)
    hidden = frames_in(local / "splats53_hidden")
    without_splats = [f for f in FRAMES if f in written and f in hidden
                      and worst_difference(written[f], hidden[f]) <= 1]
    ok = _render_tasks_completed(tasks) and not missing and worst <= 1 and not without_splats
    detail = (f"bpy {BPY53} worker; render tasks {_statuses(tasks)}, "
              f"{timings['farm_splats53_s']:.0f} s"
              + (f"; frames {without_splats} have no splats" if without_splats else "")
              + (f"; frames {missing} missing" if missing else ""))
    results.add(name, ok, f"{len(written)}/{len(FRAMES)}", f"{worst}/255", "0", detail)
    run_worker_without_extension53(farm, blender, homes, blend, evaluated, storage, hidden,
                                   results)


def run_worker_without_extension53(farm, blender, homes, blend, evaluated, storage, hidden,
                                   results) -> None:
    """A 5.3 worker without the extension: the file holds Blender's splats as Blender made them
    and no bridge (`blender_splats.ownership`), so Blender renders them by itself (Cycles'
    stochastic splats, not the exact image): every task completes and no frame lacks splats."""
    farm.start_worker("noext53", blender.env(homes / "noext53"))
    name = "on-noext53"
    job = farm.api.submit(name, job_settings({**evaluated, "frames": "1-2"}, blend,
                                             storage / "render", name))
    record, tasks = farm.wait_job(job["id"], timeout=240)
    farm.stop_worker("noext53")
    written = frames_in(job_output(record))
    without_splats = [f for f in (1, 2) if f not in written or f not in hidden
                      or worst_difference(written[f], hidden[f]) <= 1]
    ok = _render_tasks_completed(tasks) and not without_splats
    results.add(name, ok, f"{len(written)}/2", "-", "0",
                f"Blender's own renderer; render tasks {_statuses(tasks)}"
                + (f"; frames {without_splats} missing or without splats" if without_splats
                   else ""))


def run_bad_worker(farm, blender, homes, worker, blend, evaluated, storage, results,
                   expected: str, *, before_the_meshes: bool = False) -> None:
    """A job on a worker that cannot compose splats: its tasks must fail, with a message, and
    leave no frame; `before_the_meshes`: without rendering the scene's meshes first (Blender
    logs "Start rendering" when it starts the scene's own render)."""
    farm.start_worker(worker, blender.env(homes / worker))
    name = f"on-{worker}"
    settings = job_settings({**evaluated, "frames": "1-2"}, blend, storage / "render", name)
    job = farm.api.submit(name, settings)
    record, _ = farm.wait_job(job["id"], timeout=240)
    farm.stop_worker(worker)
    written = frames_in(job_output(record))
    statuses, tasks = task_summary(farm, job["id"])
    failed = [f for f, s in statuses.items() if s == "failed"]
    message, meshes_rendered = "", False
    for frame in failed:
        text = farm.api.task_log(tasks[frame]["id"])
        meshes_rendered |= "Start rendering" in text
        found = re.search(rf".*(?:{expected}).*", text)
        if found:
            message = found.group(0).strip()
    ok = bool(failed) and not written and bool(message) and not (before_the_meshes
                                                                  and meshes_rendered)
    if before_the_meshes:
        message = f"{'meshes rendered first; ' if meshes_rendered else 'before the meshes; '}{message}"
    results.add(name, ok, f"{len(written)}/2", "-",
                f"1 ({worker}: tasks {sorted(statuses.values())})",
                f"job {record['status']}; log: {message[:110]}")


if __name__ == "__main__":
    sys.exit(main())
