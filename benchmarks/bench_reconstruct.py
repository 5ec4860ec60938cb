"""Photos or a video to cameras (`python -m addon reconstruct`), measured: for each capture the
time of each stage, the peak memory of the process, the share of photos placed, and the camera
poses against a reference (rotation error in degrees and position error as a share of the scene
size, after a similarity alignment of the camera centres), and for captures in order how smooth
the camera path is (`compare.largest_step`). Numbers only, never a test.

    .venv/bin/python benchmarks/bench_reconstruct.py [--threads 2] [--only demo cup ...]
        [--features accurate|fast] [--mapper incremental|global] [--out DIR] [--render-cost]
        [--train-steps N [--seeds 0 1 ...]]

Captures: `demo` (examples/demo_colmap/images, 30 renders, reference: their exact cameras),
`cup` (77 photos, reference: the shipped COLMAP model), `beer` (71 video frames as photos,
reference: the shipped model), `beer-video` (the same 71 frames made into an MPEG-4 video at 10
fps, H.264 at CRF 18, reconstructed from the video file, frames matched to the reference by number). cup and beer
come from ../shared/data.

`--train-steps N` then trains N steps (0: until done; the default recipe, each of `--seeds`) on
the reconstruction and on
the reference model (the demo's shipped exact model, cup's and beer's shipped models) at the same
photo size (`--downscale`: cup and beer are trained at a quarter of their size) and prints the
held-out PSNR of each (every 8th photo by name held out: the same photos in both, when every
photo is placed). Runs of one recipe drift by themselves (docs/benchmarks/training_sizes.md).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from addon.core.sfm.compare import largest_step, model_poses, pose_errors  # noqa: E402
from addon.core.child import environment  # noqa: E402
from addon.core.sfm.process import command  # noqa: E402
from videos import photos_as_video  # noqa: E402

DATA = ROOT.parent / "shared" / "data"
DEMO = ROOT / "examples" / "demo_colmap"


def demo_truth(pycolmap) -> dict:
    known = json.loads((DEMO / "known_poses.json").read_text())
    flip = np.diag([1.0, -1.0, -1.0])  # Blender's camera axes to OpenCV's
    return {n: (np.array(v["camera_to_world"])[:3, :3] @ flip,
                np.array(v["camera_to_world"])[:3, 3]) for n, v in known["images"].items()}


def held_out_psnr(workspace: Path, downscale: float, steps: int, threads: int,
                  cache: Path, seed: int) -> tuple[float, int]:
    from addon.core.colmap import read_colmap
    from addon.core.train.dataset import ColmapDataset
    from addon.core.train.trainer import Trainer, TrainConfig, compact

    scene = read_colmap(workspace, image_folder="images", cache_dir=cache)
    dataset = ColmapDataset(scene, downscale=downscale)
    dataset.preload(threads=threads)
    trainer = Trainer(dataset, TrainConfig(steps=steps, seed=seed, threads=threads))
    for _ in trainer.run():
        pass
    if trainer.until_done:
        compact(trainer)  # as the product's own run until done ends
    return trainer.evaluate().psnr, len(dataset.test_indices)


def render_cost(pycolmap, workspace: Path, threads: int) -> None:
    """Gaussians trained on the demo's exact cameras, rendered through the reconstruction's
    cameras (moved into the exact frame by the similarity of the centres, distortion left out)
    and through the exact ones: the PSNR our camera errors cost, without training noise."""
    from addon.core.cameras import Camera
    from addon.core.colmap import read_colmap
    from addon.core.images import files
    from addon.core.render.renderer import render
    from addon.core.train.dataset import ColmapDataset
    from addon.core.train.trainer import Trainer, TrainConfig

    scene = read_colmap(DEMO, "images", cache_dir=workspace.parent / "train-cache")
    dataset = ColmapDataset(scene)
    dataset.preload(threads=threads)
    trainer = Trainer(dataset, TrainConfig(steps=2000, seed=0, threads=threads))
    for _ in trainer.run():
        pass
    ours = pycolmap.Reconstruction(str(workspace / "sparse" / "0"))
    by_name = {im.name: im for im in ours.images.values()}
    names = [im.name for im in scene.images]
    sim = pycolmap.estimate_sim3d(np.array([by_name[n].projection_center() for n in names]),
                                  np.array([im.camera.centre for im in scene.images]))
    rotation, shift = np.asarray(sim.rotation.matrix()), np.asarray(sim.translation)
    (camera,) = ours.cameras.values()
    focal, cx, cy = camera.params[:3]

    def psnr(cam, photo) -> float:
        rgb = np.clip(render(trainer.gaussians, cam, background=trainer.background).rgb, 0, 1)
        return float(-10 * np.log10(np.mean((rgb - photo) ** 2)))

    rows = []
    for k, im in enumerate(scene.images):
        photo = files.to_float(files.read_pixels(im.path))[:, :, :3]
        m = np.asarray(by_name[im.name].cam_from_world().matrix())
        w2c = np.eye(4)
        w2c[:3, :3] = m[:, :3] @ rotation.T
        w2c[:3, 3] = -m[:, :3] @ rotation.T @ shift + sim.scale * m[:, 3]
        mine = Camera(w2c, focal, focal, cx, cy, im.camera.width, im.camera.height)
        rows.append((k in dataset.test_indices, psnr(im.camera, photo), psnr(mine, photo)))
    rows = np.array(rows)
    held = rows[rows[:, 0] == 1]
    print(f"demo render cost: all views exact {rows[:, 1].mean():.2f} dB, ours "
          f"{rows[:, 2].mean():.2f} dB; held-out exact {held[:, 1].mean():.2f}, ours "
          f"{held[:, 2].mean():.2f} dB", flush=True)


def run(source: Path, out: Path, options: dict) -> tuple[dict, float, float]:
    """The verb in its own process: (report, wall seconds, its peak resident MB)."""
    started = time.perf_counter()
    done = subprocess.run(command(source, out, options), capture_output=True, text=True,
                          env=environment())
    seconds = time.perf_counter() - started
    last = [json.loads(line) for line in done.stdout.splitlines() if line.startswith('{"report"')]
    if done.returncode != 0 or not last:
        raise RuntimeError(f"{source}: the reconstruction failed (status {done.returncode})")
    return last[0]["report"], seconds, last[0]["peak_mb"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--mapper", default="incremental")
    parser.add_argument("--features", default="accurate", choices=("accurate", "fast"))
    parser.add_argument("--render-cost", action="store_true",
                        help="demo: what our cameras cost a render of Gaussians trained 2,000 "
                             "steps on the exact ones (PSNR through ours against through exact)")
    parser.add_argument("--only", nargs="*", default=["demo", "cup", "beer", "beer-video"])
    parser.add_argument("--out", type=Path, help="keep the workspaces here")
    parser.add_argument("--train-steps", type=int, default=None,
                        help="also train this many steps on each and its reference (0: until "
                             "done, the default recipe's stop)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0], help="training seeds")
    args = parser.parse_args()
    import pycolmap

    work = args.out or Path(tempfile.mkdtemp(prefix="bench-reconstruct-"))
    rows, trained = [], []
    for name in args.only:
        out = work / name
        if name == "demo":
            source, truth, reference_dir, downscale = DEMO / "images", demo_truth(pycolmap), DEMO, 1
        else:
            capture = "beer" if name.startswith("beer") else name
            reference = pycolmap.Reconstruction(str(DATA / capture / "sparse" / "0"))
            truth = model_poses(reference)
            source, reference_dir, downscale = DATA / capture / "images", DATA / capture, 4
            if name == "beer-video":
                frames = sorted(source.iterdir())
                source = work / "beer.mp4"
                work.mkdir(parents=True, exist_ok=True)
                photos_as_video(frames, source)
                # frame_00012.jpg is the 13th frame, 0012.jpg in the reference
                truth = {f"frame_{int(Path(n).stem):05d}.jpg": pose for n, pose in truth.items()}
        report, seconds, peak = run(source, out, {"threads": args.threads, "mapper": args.mapper,
                                                  "features": args.features})
        if name == "demo" and args.render_cost:
            render_cost(pycolmap, out, args.threads)
        found = model_poses(pycolmap.Reconstruction(str(out / "sparse" / "0")))
        errors = pose_errors(pycolmap, found, truth)
        stages = report["seconds"]
        rows.append((name, f"{len(report['registered'])}/{report['photos']}",
                     report["matching"], *(f"{stages.get(s, 0):.1f}" for s in
                                           ("photos", "features", "matching", "mapping")),
                     f"{seconds:.1f}", f"{peak:.0f}",
                     f"{np.median(errors.rotation_deg):.3f} / {errors.rotation_deg.max():.3f}",
                     f"{100 * np.median(errors.position):.3f} / {100 * errors.position.max():.3f}",
                     f"{largest_step(found):.1f} / {largest_step(truth):.1f}"))
        print(f"{name}: {report['photos']} photos, {errors.summary()}", flush=True)
        for seed in args.seeds if args.train_steps is not None else ():
            cache = work / "train-cache"
            ours = held_out_psnr(out, downscale, args.train_steps, args.threads, cache, seed)
            theirs = held_out_psnr(reference_dir, downscale, args.train_steps, args.threads,
                                   cache, seed)
            trained.append((name, str(seed), f"1/{downscale}", str(ours[1]), f"{theirs[0]:.2f}",
                            f"{ours[0]:.2f}", f"{ours[0] - theirs[0]:+.2f}"))
            print(f"{name}: held-out PSNR, seed {seed}: reference {theirs[0]:.2f} dB, "
                  f"reconstruction {ours[0]:.2f} dB", flush=True)
    header = ("capture", "placed", "matching", "photos s", "features s", "matching s",
              "mapping s", "total s", "peak MB", "rotation err median / max (deg)",
              "position err median / max (% of scene)",
              "largest step between consecutive cameras, ours / reference (median steps)")
    print()
    print("| " + " | ".join(header) + " |")
    print("|" + " --- |" * len(header))
    for row in rows:
        print("| " + " | ".join(row) + " |")
    print(f"\n{args.threads} threads, {args.features} features, {args.mapper} mapping, "
          f"workspaces in {work}")
    if trained:
        header = ("capture", "seed", "size", "held-out views", "reference PSNR",
                  "reconstruction PSNR", "difference")
        print(f"\nTrained {f'{args.train_steps} steps' if args.train_steps else 'until done'}:\n")
        print("| " + " | ".join(header) + " |")
        print("|" + " --- |" * len(header))
        for row in trained:
            print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
