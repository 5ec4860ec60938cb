"""The command line: one parser and one implementation per verb, for both entry points.

    blender -c gaussian_splatting <verb> [options]    Blender 4.2+ with the extension enabled
    python -m addon <verb> [options]                  this project's venv (the bpy wheel)

Verbs (each has `--help`):
    reconstruct PHOTOS|VIDEO --out FOLDER              photos or a video to a COLMAP workspace
    import-colmap FOLDER --out scene.blend             COLMAP cameras, photos and points
    train FOLDER|scene.blend --out out.ply|out.blend   train Gaussians on the CPU
    render scene.blend --out /tmp/frame_ [--frames 1-24]
    export scene.blend --out rig.ply [--frames 1-48]   a splat object (posed, deformed) to files
    convert-to-mesh in.ply|scene.blend --out mesh.blend
    convert in.ply out.spz [--forward Z --up -Y]       splat file to splat file

Every verb but `convert` and `reconstruct` runs Blender's own operators (the ones the menus
run, with their defaults: an option left out here is the operator's default), headless: long
jobs print a line per stage and every few seconds. `convert` and `reconstruct` need no
Blender at all. Exit status: 0 done, 1 the work failed (the reason on stderr, once), 2 bad
arguments (an unknown verb or option, a bad value, an output name whose extension the verb
cannot write).

`python -m addon` needs this repository on Python's path: run it from the repository root, or
anywhere after `scripts/bootstrap.sh`, which puts the repository on the venv's path.

Parsing is Blender-free, so `--help` is instant; `bpy` is imported only by the verbs that need
it (inside Blender that is Blender's own; in the venv the bpy wheel, with the add-on registered
from this package).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
from pathlib import Path
from typing import Callable, Sequence

from .core import axes
from .core.sfm.mapping import MAPPERS
from .core.sfm.pairs import METHODS as MATCHING
from .core.sfm.pipeline import CAMERAS, FEATURES
from .core.train.config import STRATEGY_NAMES

COMMAND_ID = "gaussian_splatting"  # `blender -c gaussian_splatting ...` (the extension's id)


class CommandError(Exception):
    """A verb cannot do its work: the message says why (exit status 1)."""


class BadArgument(CommandError):
    """An argument only Blender can check is wrong (an engine id): exit status 2."""


# -- shared pieces ---------------------------------------------------------------------------

def _axis(text: str) -> str:
    if str(text).upper() == "AUTO":
        return "AUTO"
    try:
        return axes.parse_axis(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def _add_axes(parser: argparse.ArgumentParser, prefix: str = "", what: str = "the file") -> None:
    dest = prefix.replace("-", "_")
    parser.add_argument(f"--{prefix}forward", dest=f"{dest}forward", type=_axis, default="AUTO",
                        metavar="AXIS", help=f"axis of {what} that is Blender's forward (+Y): "
                        "X, Y, Z, -X, -Y, -Z or auto (the format's convention; default)")
    parser.add_argument(f"--{prefix}up", dest=f"{dest}up", type=_axis, default="AUTO",
                        metavar="AXIS", help=f"axis of {what} that is Blender's up (+Z) "
                        "(default auto)")


def _frames(text: str) -> tuple[int, int]:
    try:
        first, _, last = text.partition("-")
        first_frame = int(first)
        last_frame = int(last) if last else first_frame
    except ValueError:
        raise argparse.ArgumentTypeError(f"frames {text!r}: expected N or FIRST-LAST") from None
    if last_frame < first_frame:
        raise argparse.ArgumentTypeError(f"frames {text!r}: the last is before the first")
    return first_frame, last_frame


def _blender():
    """bpy with the add-on's operators registered (in the venv, from this package)."""
    import bpy

    if not hasattr(bpy.types, "SPLAT_OT_import_splats"):
        from . import register
        register()
    return bpy


def _empty_scene(bpy) -> None:
    # The factory startup, emptied (preferences, and so the enabled extensions, are kept).
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    _blender()


def _check_available(modules, feature: str) -> None:
    """The feature's modules before any work (one clear line, not the operator's failure)."""
    from .blender import dependencies

    reason = dependencies.unavailable(modules, feature)
    if reason is not None:
        raise CommandError(reason)


def _open(bpy, path: Path) -> None:
    if not path.is_file():
        raise CommandError(f"{path}: no such .blend file")
    bpy.ops.wm.open_mainfile(filepath=str(path))
    _blender()


def _save(bpy, path: Path) -> None:
    path = path.resolve()
    if not path.parent.is_dir():
        raise CommandError(f"{path}: folder {path.parent} does not exist")
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    print(f"saved {path}", flush=True)


def _options(args: argparse.Namespace, names: Sequence[str]) -> dict:
    """The operator options given on the command line (left out: the operator's default)."""
    return {name: getattr(args, name) for name in names if getattr(args, name) is not None}


def _splat_object(bpy, source: Path, object_name: str | None, forward: str, up: str):
    """A splat object: imported from a splat file, or named (or the only one) in a .blend."""
    from .blender.io import operators
    from .blender.blender_splats import any_splats

    if source.suffix.lower() == ".blend":
        _open(bpy, source)
        candidates = [o for o in bpy.context.scene.objects if any_splats.is_splat_source(o)]
        if object_name:
            candidates = [o for o in candidates if o.name == object_name]
        if len(candidates) != 1:
            names = ", ".join(o.name for o in candidates) or "none"
            raise CommandError(f"{source}: name the splat object with --object (splat objects: "
                               f"{names})")
        return candidates[0]
    _empty_scene(bpy)
    return operators.import_splats(source, forward_axis=forward, up_axis=up)


def _activate(bpy, obj) -> None:
    layer = bpy.context.view_layer
    layer.update()
    for other in layer.objects:
        other.select_set(False)
    obj.select_set(True)
    layer.objects.active = obj


# -- verbs -----------------------------------------------------------------------------------

def _import_colmap(args: argparse.Namespace) -> None:
    bpy = _blender()
    from .blender.io import colmap_import
    _check_available(colmap_import.MODULES, colmap_import.FEATURE)
    _empty_scene(bpy)
    options = _options(args, ("image_folder", "align", "scene_size", "points", "render_points",
                              "backgrounds", "animated_camera", "cache_dir", "photo_colours",
                              "mesh_light"))
    if args.up_from is not None:
        options["up_axis"] = args.up_from.upper()
    bpy.ops.splat.import_colmap(directory=str(Path(args.folder).resolve()), **options)
    _save(bpy, Path(args.out))


def _train(args: argparse.Namespace) -> None:
    bpy = _blender()
    from .blender.train import operator
    _check_available(operator.MODULES, operator.FEATURE)
    source = Path(args.source)
    if source.suffix.lower() == ".blend":
        _open(bpy, source)
    else:
        _empty_scene(bpy)
        bpy.ops.splat.import_colmap(directory=str(source.resolve()),
                                    **_options(args, ("image_folder",)))
    collection = operator.find_colmap_collection(bpy.context, args.collection or "")
    if collection is None:
        raise CommandError(f"{source}: no single COLMAP scene to train (name it with "
                           f"--collection)")
    options = _options(args, ("steps", "max_gaussians", "strategy", "sh_degree", "downscale", "max_width",
                              "seed", "threads", "antialiased", "compact", "resume",
                              "checkpoint"))
    if args.image_folder is not None and source.suffix.lower() == ".blend":
        options["image_folder"] = args.image_folder
    bpy.ops.splat.train(collection=collection.name, **options)
    obj = collection.get(operator.OBJECT_KEY)
    if obj is not None and bpy.data.objects.get(obj.name) != obj:
        obj = None
    out = Path(args.out)
    if out.suffix.lower() == ".blend":
        _save(bpy, out)
        return
    if obj is None:
        raise CommandError("training made no splat object")
    _export(bpy, obj, out, args.forward, args.up)


def _export(bpy, obj, out: Path, forward: str, up: str) -> None:
    from .blender.io import operators
    for warning in operators.export_splats(obj, out, forward_axis=forward, up_axis=up):
        print(f"warning: {warning}", file=sys.stderr)
    print(f"wrote {out}", flush=True)


def _export_verb(args: argparse.Namespace) -> None:
    """The splat object as the scene shows it at the current frame, or at each of --frames to
    one file per frame (the sequence the importer reads back)."""
    from .blender.io import operators, sequence

    bpy = _blender()
    obj = _splat_object(bpy, Path(args.blend), args.object, args.forward, args.up)
    if args.frames is None:
        _export(bpy, obj, Path(args.out), args.forward, args.up)
        return
    first, last = args.frames
    pattern = sequence.sequence_pattern(Path(args.out).resolve())
    written = operators.export_sequence(obj, pattern, range(first, last + 1),
                                        forward_axis=args.forward, up_axis=args.up)
    print(f"wrote {len(written)} frames to {pattern}", flush=True)


def _render(args: argparse.Namespace) -> None:
    bpy = _blender()
    _open(bpy, Path(args.blend))
    scene = bpy.context.scene
    if args.camera:
        camera = scene.objects.get(args.camera)
        if camera is None or camera.type != "CAMERA":
            raise CommandError(f"{args.blend}: no camera object named {args.camera!r}")
        scene.camera = camera
    if args.engine:
        try:
            scene.render.engine = args.engine
        except TypeError as error:  # Blender's message lists the engines there are
            found = str(error).partition(" not found in ")[2]
            raise BadArgument(f"--engine {args.engine}: not a render engine here"
                              + (f" (engines: {found})" if found else "")) from None
    first, last = args.frames or (scene.frame_current, scene.frame_current)
    out = str(Path(args.out).resolve()) if args.out else scene.render.filepath
    # Frame by frame, as stills: each frame gets its own camera's output size (markers).
    for frame in range(first, last + 1):
        scene.frame_set(frame)
        scene.render.filepath = out
        path = scene.render.frame_path(frame=frame)
        scene.render.filepath = path
        if bpy.ops.render.render(write_still=True) != {"FINISHED"}:
            raise CommandError(f"frame {frame}: the render did not finish")
        size = (scene.render.resolution_x * scene.render.resolution_percentage // 100,
                scene.render.resolution_y * scene.render.resolution_percentage // 100)
        camera = scene.camera.name if scene.camera is not None else "no camera"
        print(f"frame {frame} ({camera}, {size[0]}x{size[1]}) -> {path}", flush=True)
    scene.render.filepath = out


def _convert_to_mesh(args: argparse.Namespace) -> None:
    bpy = _blender()
    from .blender import mesh_convert
    _check_available(mesh_convert.MODULE, mesh_convert.FEATURE)
    obj = _splat_object(bpy, Path(args.source), args.object, args.forward, args.up)
    _activate(bpy, obj)
    options = _options(args, ("resolution", "max_triangles", "texture_size", "cameras",
                              "view_count", "view_size", "proxy"))
    bpy.ops.splat.convert_to_mesh(**options)
    for image in bpy.data.images:
        if image.source == "GENERATED" or image.is_dirty:
            image.pack()
    _save(bpy, Path(args.out))


def _reconstruct(args: argparse.Namespace) -> None:
    """Photos or a video to a COLMAP workspace, without Blender. `--json` (for the add-on's
    operator, which runs this verb in a process of its own) prints one JSON object a line:
    {"step": ...} as it goes, then {"report": ...}; errors go to stderr as for every verb. In a
    Blender that must not load pycolmap (a Linux distribution's build), the work runs in a
    process of that Blender's own Python, which can."""
    import json
    import time

    from .core import sfm
    from .core.colmap.errors import pycolmap_refusal

    names = ("frames", "max_size", "features", "cameras", "matching", "mapper", "threads")
    last = {"stage": None, "at": float("-inf")}

    def on_step(step: sfm.Step) -> None:
        if args.json:
            print(json.dumps({"step": step.to_json()}), flush=True)
            return
        now = time.monotonic()
        if step.stage != last["stage"] or now - last["at"] >= 2.0 or step.done == step.total:
            last.update(stage=step.stage, at=now)
            print(f"Reconstructing: {step.line()} ({100 * step.fraction:.0f} %)", flush=True)

    if pycolmap_refusal() is not None and not args.json:
        report = _reconstruct_in_a_process(args, names, on_step)
    else:
        report = sfm.run(args.source, args.out, sfm.Options(**_options(args, names)),
                         on_step=on_step)
    if args.json:
        from .core.sfm.process import peak_memory_mb
        print(json.dumps({"report": report.to_json(), "peak_mb": peak_memory_mb()}), flush=True)
    else:
        print(report.summary(), flush=True)


def _reconstruct_in_a_process(args: argparse.Namespace, names, on_step):
    import time

    from .core import sfm
    from .core.sfm.process import ReconstructionProcess

    process = ReconstructionProcess(args.source, args.out, _options(args, names))
    seen = None
    try:
        while process.running:
            if process.step is not None and process.step is not seen:
                seen = process.step
                on_step(sfm.Step(**{k: seen[k] for k in ("stage", "done", "total", "unit",
                                                         "eta")}))
            time.sleep(0.2)
        return sfm.Report.from_json(process.report())
    finally:
        process.stop()


def _convert(args: argparse.Namespace) -> None:
    """File to file without Blender: read, take the input's frame to Blender's and Blender's
    to the output's (one rotation, snapped: the identity leaves the data untouched), write."""
    from .core.formats import registry
    from .core.transform import transform_gaussians

    source, target = Path(args.input), Path(args.output)
    if not target.parent.is_dir():
        raise CommandError(f"{target}: folder {target.parent} does not exist")

    def frame(path: Path, forward: str, up: str):
        default_forward, default_up = registry.format_for(path).axes
        return axes.axis_matrix4(default_forward if forward == "AUTO" else forward,
                                 default_up if up == "AUTO" else up)

    import numpy as np

    into_blender = frame(source, args.forward, args.up)
    out_of_blender = np.linalg.inv(frame(target, args.out_forward, args.out_up))
    gaussians, antialiased = registry.read(source)
    gaussians = transform_gaussians(gaussians, axes.snap(out_of_blender @ into_blender))
    for warning in registry.write(gaussians, target, antialiased=antialiased):
        print(f"warning: {warning}", file=sys.stderr)
    print(f"{source} -> {target}: {len(gaussians):,} splats", flush=True)


# -- the parser ------------------------------------------------------------------------------

def build_parser(prog: str) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=prog, description="Gaussian Splatting for Blender, from the command line.",
        epilog="Each verb has --help. Options left out take the operator's default "
               "(docs/guide/blender.md).")
    verbs = parser.add_subparsers(dest="verb", metavar="VERB", required=True)

    p = verbs.add_parser("reconstruct", help="photos or a video to a COLMAP workspace "
                         "(no Blender needed)",
                         description="Find the cameras of a folder of photos or a video "
                                     "(structure from motion: SIFT, matching and mapping by "
                                     "COLMAP on the CPU) and write a COLMAP workspace that "
                                     "import-colmap and train take as it is. Each stage is "
                                     "cached in FOLDER: running again resumes.")
    p.add_argument("source", help="a folder of JPEG/PNG/TIFF photos, or a video file")
    p.add_argument("--out", required=True, help="the workspace folder (new, empty, or an "
                                                "earlier reconstruction's)")
    p.add_argument("--frames", type=int, help="frames taken from a video, the sharpest of "
                                              "each time slice (default 200)")
    p.add_argument("--max-size", type=int, help="long side of the workspace's photos in "
                                                "pixels (default 1600; 0: as they are)")
    p.add_argument("--features", choices=FEATURES,
                   help="accurate (default: DSP-SIFT with affine shapes, the more exact cameras) "
                        "or fast (plain SIFT, about a third of the extraction time)")
    p.add_argument("--cameras", choices=CAMERAS,
                   help="auto (default: a camera per photo for photos, one shared by a video's "
                        "frames), shared, or per-photo")
    p.add_argument("--matching", choices=MATCHING,
                   help="which photos are matched (default auto: sequential for a video, "
                        "exhaustive up to 100 photos, retrieval beyond)")
    p.add_argument("--mapper", choices=MAPPERS,
                   help="COLMAP's mapper (default incremental; global is faster but folded the "
                        "demo's ring of cameras in 2 runs of 12)")
    p.add_argument("--threads", type=int, help="0: every core (default)")
    p.add_argument("--json", action="store_true", help=argparse.SUPPRESS)
    p.set_defaults(run=_reconstruct)

    p = verbs.add_parser("import-colmap", help="COLMAP cameras, photos and points to a .blend",
                         description="Import a COLMAP (or GLOMAP) workspace or model folder into "
                                     "an empty scene and save it as a .blend.")
    p.add_argument("folder", help="COLMAP workspace (with sparse/0) or model folder")
    p.add_argument("--out", required=True, help="the .blend to write")
    p.add_argument("--images", dest="image_folder", help="image folder beside the model: "
                   "images (default), images_2, images_4, images_8, or an absolute path")
    p.add_argument("--no-align", dest="align", action="store_false", default=None,
                   help="keep COLMAP's frame (default: stand the scene upright, centred, scaled)")
    p.add_argument("--up-from", choices=("auto", "cameras"), help="how the up direction is "
                   "found when aligning (default auto: cameras' horizon and the ground)")
    p.add_argument("--scene-size", type=float, help="median camera distance after aligning")
    p.add_argument("--no-points", dest="points", action="store_false", default=None,
                   help="leave the sparse points out")
    p.add_argument("--render-points", action="store_true", default=None,
                   help="show the sparse points in final renders too (default: viewport only)")
    p.add_argument("--no-backgrounds", dest="backgrounds", action="store_false", default=None,
                   help="no photos as camera backgrounds")
    p.add_argument("--animated-camera", action="store_true", default=None,
                   help="also a camera that follows the photos, one frame each")
    p.add_argument("--cache-dir", help="where undistorted photos go")
    p.add_argument("--keep-view-transform", dest="photo_colours", action="store_false",
                   default=None, help="keep Blender's default view transform (AgX) instead of "
                   "Standard, which shows the splats with the photos' colours")
    p.add_argument("--no-mesh-light", dest="mesh_light", action="store_false", default=None,
                   help="no World lighting meshes (default: one, invisible to the camera)")
    p.set_defaults(run=_import_colmap)

    p = verbs.add_parser("train", help="train Gaussians from a COLMAP scene",
                         description="Train Gaussians on the CPU from a COLMAP folder (imported "
                                     "first) or a .blend holding an imported COLMAP scene; "
                                     "write the splats (.ply, .spz, ...) or save a .blend.")
    p.add_argument("source", help="COLMAP folder, or a .blend with an imported COLMAP scene")
    p.add_argument("--out", required=True, help="splat file (.ply, .spz, ...) or .blend")
    p.add_argument("--collection", help="the COLMAP collection in the .blend (default: the only one)")
    p.add_argument("--images", dest="image_folder", help="image folder (images_4, ...)")
    p.add_argument("--steps", type=int, help="a fixed number of optimisation steps (default: "
                                             "until done, when the held-out PSNR gains less "
                                             "than 0.1 dB a minute)")
    p.add_argument("--max-gaussians", type=int,
                   help="a ceiling on the Gaussian count (the strategy sizes the model below it)")
    p.add_argument("--strategy", choices=STRATEGY_NAMES,
                   help="how the Gaussians grow: auto (the default: as many as the images "
                        "need), mcmc (to the ceiling), default (the reference's)")
    p.add_argument("--sh-degree", type=int, choices=range(4), help="SH bands to train")
    p.add_argument("--downscale", type=float, help="divide the photos' size by this")
    p.add_argument("--max-width", type=int, help="photos wider than this train at this width "
                   "(default 1600, as the reference 3DGS code; 0: full size)")
    p.add_argument("--seed", type=int)
    p.add_argument("--threads", type=int, help="0: every core")
    p.add_argument("--antialiased", action="store_true", default=None,
                   help="train for the antialiased (Mip) render mode")
    p.add_argument("--compact", action=argparse.BooleanOptionalAction, default=None,
                   help="prune negligible Gaussians and SH bands afterwards (default: on)")
    p.add_argument("--checkpoint", help="checkpoint file")
    p.add_argument("--resume", action="store_true", default=None,
                   help="continue from the checkpoint")
    _add_axes(p, what="the written splat file")
    p.set_defaults(run=_train)

    p = verbs.add_parser("render", help="render frames of a .blend, each at its camera's size",
                         description="Render frames of a .blend as stills, one by one, so each "
                                     "frame gets its own camera's recorded output size and "
                                     "pixel aspect (COLMAP cameras, markers); splats composed "
                                     "with the meshes as in F12.")
    p.add_argument("blend", help="the .blend to render")
    p.add_argument("--out", help="output path prefix, # for the frame number as in Blender "
                   "(default: the scene's output path)")
    p.add_argument("--frames", type=_frames, help="N or FIRST-LAST (default: the current frame)")
    p.add_argument("--camera", help="camera object to render from (default: the scene's)")
    p.add_argument("--engine", help="render engine id (default: the scene's)")
    p.set_defaults(run=_render)

    p = verbs.add_parser("export", help="a splat object of a .blend to splat files",
                         description="Write a splat object of a .blend as the scene shows it "
                                     "(modifiers, shape keys, an armature: the Gaussians "
                                     "deformed) at the current frame, or with --frames at each "
                                     "frame to one file per frame: the numbered sequence web "
                                     "viewers and Import as Sequence read.")
    p.add_argument("blend", help="the .blend holding the splat object")
    p.add_argument("--out", required=True, help="splat file to write; with --frames, # (or "
                   "%%04d) where the frame number goes (_#### is added before the extension "
                   "when missing)")
    p.add_argument("--object", help="the splat object (default: the only one)")
    p.add_argument("--frames", type=_frames, help="N or FIRST-LAST: one file per frame "
                   "(default: one file, the current frame)")
    _add_axes(p, what="the written splat files")
    p.set_defaults(run=_export_verb)

    p = verbs.add_parser("convert-to-mesh", help="splats to a textured mesh in a .blend",
                         description="Convert splats (a splat file, or a splat object in a "
                                     ".blend) to a textured triangle mesh and save a .blend "
                                     "with the texture packed.")
    p.add_argument("source", help="splat file or .blend")
    p.add_argument("--out", required=True, help="the .blend to write")
    p.add_argument("--object", help="the splat object in a .blend (default: the only one)")
    p.add_argument("--resolution", type=int, help="volume cells along the longest side")
    p.add_argument("--max-triangles", type=int, help="triangle budget")
    p.add_argument("--texture-size", type=int, help="texture width and height")
    p.add_argument("--cameras", choices=("AUTO", "COLMAP", "SPHERE"), type=str.upper)
    p.add_argument("--view-count", type=int, help="cameras on the sphere")
    p.add_argument("--view-size", type=int, help="largest side of each depth render")
    p.add_argument("--proxy", action="store_true", default=None,
                   help="make the mesh a shadow catcher and collider for the splats")
    _add_axes(p, what="the splat file")
    p.set_defaults(run=_convert_to_mesh)

    p = verbs.add_parser("convert", help="splat file to splat file (no Blender needed)",
                         description="Read a splat file and write it in the format the output "
                                     "name says, converting axes: the input's --forward/--up "
                                     "to Blender's frame, Blender's to the output's "
                                     "--out-forward/--out-up (SH rotated with it). With the "
                                     "defaults the data keeps its frame.")
    p.add_argument("input")
    p.add_argument("output")
    _add_axes(p, what="the input")
    _add_axes(p, prefix="out-", what="the output")
    p.set_defaults(run=_convert)
    return parser


AXIS_FLAGS = ("--forward", "--up", "--out-forward", "--out-up")


def _join_negative_axes(argv: list[str]) -> list[str]:
    """`--up -Y` as `--up=-Y`: argparse takes a value starting with '-' for an option."""
    out: list[str] = []
    for arg in argv:
        if out and out[-1] in AXIS_FLAGS and arg.upper() in ("-X", "-Y", "-Z"):
            out[-1] = f"{out[-1]}={arg}"
        else:
            out.append(arg)
    return out


KNOWN_ERRORS: tuple[type[BaseException], ...] = (CommandError, ValueError, OSError, RuntimeError)


def _splat_extension(path: str, *, write: bool) -> str | None:
    """Why `path`'s name is no splat format this can read (write), or None."""
    from .core.formats import registry
    try:
        fmt = registry.format_for(Path(path))
    except ValueError:
        fmt = None
    if fmt is None or (write and not fmt.can_write):
        formats = registry.export_formats() if write else registry.FORMATS
        names = ", ".join(dict.fromkeys(e for f in formats for e in f.endings))
        return (f"{path}: no splat format {'writes' if write else 'reads'} "
                f"{Path(path).suffix or 'a name without extension'!r} (expected {names})")
    return None


def _output_errors(args: argparse.Namespace) -> str | None:
    """Output names a verb cannot write: bad arguments (exit 2), found before any work."""
    if args.verb in ("import-colmap", "convert-to-mesh"):
        if Path(args.out).suffix.lower() != ".blend":
            return f"--out {args.out}: expected a .blend file"
    elif args.verb == "train":
        if Path(args.out).suffix.lower() != ".blend":
            return _splat_extension(args.out, write=True)
    elif args.verb == "convert":
        return _splat_extension(args.output, write=True)
    elif args.verb == "export":
        return _splat_extension(args.out, write=True) or (
            None if Path(args.blend).suffix.lower() == ".blend"
            else f"{args.blend}: expected a .blend file")
    return None


class _WithoutErrorReports(io.TextIOBase):
    """Blender writes an operator's reports to stdout ("Error: ..."), and the same error comes
    back as the exception this command prints to stderr: the copy on stdout is left out, so the
    reason is printed once. Everything else passes straight through (progress lines)."""

    def __init__(self, stream) -> None:
        self.stream = stream

    def write(self, text: str) -> int:
        if not text.startswith("Error: "):
            self.stream.write(text)
        return len(text)

    def flush(self) -> None:
        self.stream.flush()


def main(argv: Sequence[str] | None = None, prog: str = "python -m addon") -> int:
    """Run one verb; returns the exit status (never raises for bad input or a failed job)."""
    parser = build_parser(prog)
    try:
        args = parser.parse_args(_join_negative_axes(list(sys.argv[1:] if argv is None else argv)))
    except SystemExit as exit_:  # --help (0) or bad arguments (2): argparse printed why
        return int(exit_.code or 0)
    bad_output = _output_errors(args)
    if bad_output is not None:
        print(f"{prog} {args.verb}: error: {bad_output}", file=sys.stderr, flush=True)
        return 2
    run: Callable[[argparse.Namespace], None] = args.run
    try:
        with contextlib.redirect_stdout(_WithoutErrorReports(sys.stdout)):
            run(args)
    except KNOWN_ERRORS as error:
        message = str(error).strip() or type(error).__name__
        message = message.removeprefix("Error: ")  # bpy.ops' RuntimeError repeats the level
        print(f"{prog} {args.verb}: error: {message}", file=sys.stderr, flush=True)
        return 2 if isinstance(error, BadArgument) else 1
    return 0
