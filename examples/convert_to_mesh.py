"""Convert splats to a textured mesh, headless, and save a .blend.

    .venv/bin/python examples/convert_to_mesh.py                      # the demo scene
    .venv/bin/python examples/convert_to_mesh.py scene.ply --resolution 128 \
        --max-triangles 50000 --texture-size 1024 --proxy --out /tmp/mesh.blend
    blender --background --python examples/convert_to_mesh.py -- scene.ply --out mesh.blend

Loads the .ply as a splat object, runs the conversion (`mesh_convert.convert_to_mesh`, what
`bpy.ops.splat.convert_to_mesh` runs), packs the texture into the .blend and prints the
triangle count, texture size and time per stage. Without the statistics, the command line does
the same: `python -m addon convert-to-mesh scene.ply --out mesh.blend` (or `blender -c
gaussian_splatting convert-to-mesh ...`; docs/guide/scripts.md).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def main(argv: list[str]) -> None:
    argv = argv[argv.index("--") + 1:] if "--" in argv else argv[1:]
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("ply", nargs="?", default=str(ROOT / "examples" / "demo_scene.ply"))
    parser.add_argument("--resolution", type=int, default=96)
    parser.add_argument("--max-triangles", type=int, default=20_000)
    parser.add_argument("--texture-size", type=int, default=512)
    parser.add_argument("--cameras", default="AUTO", choices=("AUTO", "COLMAP", "SPHERE"))
    parser.add_argument("--proxy", action="store_true")
    parser.add_argument("--out", default="/tmp/splats_mesh.blend")
    args = parser.parse_args(argv)

    import bpy

    import addon
    from addon.blender.io import operators
    from addon.blender import mesh_convert

    bpy.ops.wm.read_factory_settings(use_empty=True)
    if not hasattr(bpy.types, "SPLAT_OT_convert_to_mesh"):
        addon.register()
    obj = operators.import_splats(args.ply)
    bpy.context.view_layer.objects.active = obj
    stats = {}
    new = mesh_convert.convert_to_mesh(
        obj, resolution=args.resolution, max_triangles=args.max_triangles,
        texture_size=args.texture_size, cameras=args.cameras, proxy=args.proxy, stats=stats,
        progress=lambda stage, f: print(f"\r{stage:>8} {100 * f:5.1f}%", end="", flush=True))
    print()
    bpy.ops.wm.save_as_mainfile(filepath=str(Path(args.out).resolve()))
    times = ", ".join(f"{k[:-2]} {v:.2f}" for k, v in stats.items() if k.endswith("_s"))
    print(f"'{new.name}': {stats['triangles']} triangles (extracted {stats['extracted_triangles']}),"
          f" {stats['texture_size']}px texture ({100 * stats['coverage']:.1f}% of texels seen), "
          f"{stats['cameras']} cameras; seconds: {times} -> {args.out}")


if __name__ == "__main__":
    main(sys.argv)
