"""Time one composite frame (meshes in Cycles at low samples, plus splats) split into its parts.

    .venv/bin/python examples/bench_render_with_meshes.py [--size 1280x720] [--samples 4]
        [--splats FILE ...] [--random N ...] [--repeat 3]

The scene is examples/render_headless.py's (a monkey and a pedestal with the splats, a sun);
`--splats` swaps the splats (e.g. ../shared/data/splats/playbot_125k_sh2.ply), `--random N`
uses N random Gaussians about the origin. For each splat set it renders the same frame with
`bpy.ops.render.render(write_still=True)` to PNG, with the splats switched off (Blender alone:
Cycles and the file; "PNG write" is the file's share, timed by saving the Render Result again)
and on, best of `--repeat`, and prints where the difference goes:

    gather    splats from the render's depsgraph (world space; cached per object)
    save      Render Result -> float EXR (Blender's Image.save_render, in a RAM folder)
    read      that EXR -> numpy (addon.core.exr_scanlines: views of the file's bytes)
    colour    scene-linear <-> display sRGB conversions of the mesh layer and the composite
    native    the native compositor (projection, sort, binning, per-pixel composite)
    result    composite -> the helper scene's render result (RenderPass.rect.foreach_set)
    other     the rest of the difference: the helper scene's render set-up and Blender's
              compositor pass (the new Render Layers node feeding the output)
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "examples"))

import bpy  # noqa: E402

import addon  # noqa: E402
import render_headless  # noqa: E402


def timed_render(scene, path: str) -> float:
    scene.render.filepath = path
    start = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--size", default="1280x720")
    parser.add_argument("--samples", type=int, default=4)
    parser.add_argument("--splats", nargs="*", default=[str(ROOT / "examples" / "demo_scene.ply")])
    parser.add_argument("--random", nargs="*", type=int, default=[])
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    addon.register()
    from addon.blender import compositor_bridge, render_hooks, splat_object
    from addon.core.native import cpu_count

    out = tempfile.mkdtemp(prefix="bench-render-")
    sets = [("file", p) for p in args.splats] + [("random", n) for n in args.random]
    print(f"{args.size}, Cycles CPU {args.samples} samples, PNG output, {cpu_count()} cores; "
          f"best of {args.repeat} (ms)")
    header = ("splats", "Blender", "(PNG write)", "with splats", "extra", "gather", "save",
              "read", "colour", "native", "result", "other")
    print(" | ".join(header))
    print(" | ".join("---" for _ in header))
    for kind, value in sets:
        scene_args = argparse.Namespace(splats=value if kind == "file" else args.splats[0],
                                        engine="CYCLES", size=args.size, samples=args.samples,
                                        frames=1, out=out, save="")
        render_headless.build_scene(bpy, scene_args)
        scene = bpy.context.scene
        if kind == "random":
            from scenes import fast_random_gaussians
            import numpy as np

            for obj in [o for o in scene.objects if splat_object.is_splat_object(o)]:
                bpy.data.objects.remove(obj)
            g = fast_random_gaussians(np.random.default_rng(0), value, degree=1)
            splat_object.create_splat_object(g, "Random")
        scene.render.image_settings.file_format = "PNG"
        count = sum(len(o.data.vertices) for o in scene.objects if splat_object.is_splat_object(o))
        scene.splat_render.enabled = False
        compositor_bridge.remove_bridge(scene)
        plain = [timed_render(scene, f"{out}/plain") for _ in range(args.repeat)]
        writes = []
        for _ in range(args.repeat):  # what writing the PNG costs (part of "Blender")
            start = time.perf_counter()
            bpy.data.images["Render Result"].save_render(f"{out}/again.png", scene=scene)
            writes.append(time.perf_counter() - start)
        scene.splat_render.enabled = True
        runs = []
        for _ in range(args.repeat):
            seconds = timed_render(scene, f"{out}/splats")
            runs.append((seconds, dict(render_hooks.last_stats)))
        seconds, stats = min(runs, key=lambda r: r[0])
        base = min(plain)
        extra = 1000 * (seconds - base)
        parts = [stats.get(k, 0.0) for k in ("gather_ms", "save_ms", "read_ms", "colour_ms",
                                               "native_ms", "result_ms")]
        row = [f"{count:,}", f"{1000 * base:.0f}", f"{1000 * min(writes):.0f}",
               f"{1000 * seconds:.0f}", f"{extra:.0f}",
               *(f"{p:.0f}" for p in parts), f"{extra - sum(parts):.0f}"]
        print(" | ".join(row), flush=True)
        spread = statistics.pstdev([1000 * r[0] for r in runs])
        print(f"    (spread of the runs with splats: {spread:.0f} ms; Blender alone: "
              f"{', '.join(f'{1000 * p:.0f}' for p in plain)} ms)")


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT / "tests"))
    main()
