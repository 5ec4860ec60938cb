"""The product as a user gets it: the linux-x64 zip in clean bpy wheels, every feature used.

    .venv/bin/python scripts/test_installed_extension.py [--bpy 4.2.23 ...] [--zip FILE]
                                                         [--cache DIR] [--keep]

For each bpy version (default BPY_VERSIONS, the newest of each supported line on PyPI), a clean
bpy holding nothing but that wheel and what pip installs with it, and a fresh, empty Blender user
folder. bpy 4.2 - 5.0 (Python 3.11) run in venvs of this machine, made once in --cache (default
~/.cache/gaussian-splatting-ci). bpy 5.1 and later are official wheels for Python 3.13, which
this machine cannot install: they run in the py313 root filesystem of ../shared/real-blender
(`bpy313.sh VERSION` builds each once; needs root), where this script, tests/real_blender, the
zip and the data are staged under its /io for the run. The stages, each in a new process:

  install   `extension validate` (that Blender's own bl_pkg/cli/blender_ext.py), then
            `bpy.ops.extensions.package_install_files(enable_on_install=True)` of the zip (the
            path of Preferences > Get Extensions > Install from Disk); every module the add-on
            needs must then import (splatcore from the extension's own site-packages).
  formats   a new session (preferences read as Blender starts; bpy 4.2 enables the extension
            instead, its read_userpref crashes): import .ply, compressed .ply, .spz (version 4,
            zstd), .splat and a streamed SOG from ../shared/data; export every format the
            extension writes and import each back.
  render    F12 (`render(write_still=True)`) in Cycles and Workbench of PLAYBOT with a cube in
            front and a plane behind, and a two-frame animation (`render(animation=True)`, as
            `blender -b -a` runs). Each written PNG must equal the native composite within
            1/255 and show both the splats and the cube. The expected image is computed here,
            in the project venv (addon.core.render.renderer, OpenImageIO from requirements.txt), from
            what the Blender process saves beside each frame: the same frame as a multilayer
            EXR (Blender's own mesh colour and depth), the splats the add-on gathered, and the
            camera; so a Blender that cannot compose (or read images) fails the check, not
            the checker.
  colmap    reconstruct 16 of cup's photos (Import Photos or Video, its child process in that
            bpy's Python); import the distorted COLMAP model ../shared/data/beer (SIMPLE_RADIAL,
            images_8), train briefly, Convert to Mesh the result, export it.
  blender_splats  (Blender 5.3 and later, which have splat point clouds of their own) the
            checks of tests/real_blender/splats53.py, run as they are (the zip installed into a
            fresh user folder of their own): Blender's importers against the add-on's, round
            trips on every shared file, the importer option, export, F12 against the add-on's
            own object, the edit tools, drop handlers.

Each check prints `PASS name` or `FAIL name: why`; the script exits non-zero on any failure
(a stage that crashes fails as a whole), after a table of every check against every version.
Without --zip it builds the zip first (scripts/build_extension.py --platform linux-x64, wheels
cached). --keep keeps the work folders.

The same file runs inside each bpy (`--inside STAGE`): there it imports only the standard
library, bpy, numpy and the installed extension.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# Plain-bpy helpers shared with the real-Blender scripts (staged with this file into the py313
# root): the PASS/FAIL check, the extension's modules, the render scene's pieces.
sys.path.append(str(ROOT / "tests" / "real_blender"))
import scene_kit  # noqa: E402
from extension_kit import EXTENSION, check, ext, install_zip  # noqa: E402

# The newest of each line on PyPI (`pip index versions bpy`): 4.2 LTS, 4.5 LTS, 5.0 (Python 3.11);
# 5.1, 5.2, 5.3 (Python 3.13).
BPY_VERSIONS = ("4.2.23", "4.5.15", "5.0.1", "5.1.2", "5.2.3", "5.3.0")
PY313_FROM = (5, 1)         # the first bpy line built for Python 3.13
BLENDER_SPLATS_FROM = (5, 3)  # the first Blender with splat point clouds of its own
STAGES = ("install", "formats", "render", "colmap", "blender_splats")
MODULES = ("splatcore", "pycolmap", "OpenImageIO", "xatlas", "zstandard", "av")


# ============================================================== the driver (project venv)

def default_cache() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "gaussian-splatting-ci"


def python311() -> str:
    for candidate in (os.environ.get("PYTHON311", ""), "python3.11"):
        if candidate and shutil.which(candidate):
            return shutil.which(candidate)
    raise SystemExit("Python 3.11 is needed for the bpy wheels (set PYTHON311=/path/to/python3.11)")


def bpy_venv(version: str, cache: Path) -> Path:
    """The venv with only bpy==version (and its own dependencies), made once."""
    venv = cache / f"bpy-{version}"
    ready = venv / ".ready"
    if ready.exists() and (venv / "bin" / "python").exists():
        return venv
    shutil.rmtree(venv, ignore_errors=True)
    print(f"[bpy {version}] creating {venv}", flush=True)
    subprocess.run([python311(), "-m", "venv", str(venv)], check=True)
    subprocess.run([str(venv / "bin" / "python"), "-m", "pip", "install", "-q",
                    "--disable-pip-version-check", f"bpy=={version}"], check=True)
    ready.write_text(version)
    return venv


def build_zip(out: Path) -> Path:
    subprocess.run([sys.executable, str(ROOT / "scripts" / "build_extension.py"), "--platform",
                    "linux-x64", "--out", str(out)], check=True)
    (zip_path,) = out.glob("gaussian_splatting-*-linux_x64.zip")
    return zip_path


def version_line(version: str) -> tuple[int, int]:
    major, minor = version.split(".")[:2]
    return int(major), int(minor)


def stages_for(version: str) -> tuple[str, ...]:
    return tuple(s for s in STAGES
                 if s != "blender_splats" or version_line(version) >= BLENDER_SPLATS_FROM)


class HostVenv:
    """bpy 4.2 - 5.0 (Python 3.11) in a venv of this machine: paths are the same on both sides."""

    def __init__(self, version: str, cache: Path, scratch: Path, zip_path: Path, data: Path):
        self.python = str(bpy_venv(version, cache) / "bin" / "python")
        self.script, self.zip, self.data = Path(__file__).resolve(), zip_path, data
        self.checks = ROOT / "tests" / "real_blender" / "splats53.py"
        self.base = scratch / f"bpy-{version}"

    def inside(self, path: Path) -> str:
        return str(path)

    def outside(self, path: str) -> Path:
        return Path(path)

    def command(self, arguments: list[str], user: Path, work: Path) -> tuple[list[str], dict]:
        env = dict(os.environ, BLENDER_USER_RESOURCES=str(user))
        env.pop("PYTHONPATH", None)
        return [self.python, *arguments], env


class InPy313Root:
    """bpy 5.1+ (official wheels for Python 3.13) in ../shared/real-blender's py313 root
    (scripts/py313_root.py): this script, tests/real_blender, the zip and the data the stages
    read are staged under its /io once per run (`staged`, shared by the versions)."""

    staged: Path | None = None

    def __init__(self, version: str, zip_path: Path, data: Path):
        sys.path.insert(0, str(ROOT / "scripts"))
        from py313_root import Py313Root, copy_tree

        self.where = Py313Root(version)
        if InPy313Root.staged is None:
            staged = self.where.stage_dir("installed-extension-")
            (staged / "checkout" / "scripts").mkdir(parents=True)
            shutil.copy2(__file__, staged / "checkout" / "scripts")
            copy_tree(ROOT / "tests" / "real_blender", staged / "checkout" / "tests"
                      / "real_blender")
            shutil.copy2(zip_path, staged)
            for name in ("splats", "beer", "cup"):  # what the stages read
                copy_tree(data / name, staged / "data" / name)
            InPy313Root.staged = staged
        self.script = self.staged / "checkout" / "scripts" / Path(__file__).name
        self.checks = self.staged / "checkout" / "tests" / "real_blender" / "splats53.py"
        self.zip, self.data = self.staged / zip_path.name, self.staged / "data"
        self.base = self.staged / f"bpy-{version}"
        self.inside, self.outside = self.where.inside, self.where.outside

    def command(self, arguments: list[str], user: Path, work: Path) -> tuple[list[str], dict]:
        env = {"BLENDER_USER_RESOURCES": self.inside(user)}
        return self.where.command(arguments, cwd=work, env=env), dict(os.environ)


def run_process(command: list[str], env: dict, cwd: Path, timeout: float) -> tuple[str, object]:
    """(stdout then stderr, exit status or "timeout"); on a timeout the whole process group is
    killed (run.sh's chroot leaves the Python process a grandchild). The streams are read
    apart: Blender writes reports to one without a line end, which would hide a check line."""
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True, env=env, cwd=cwd, start_new_session=True)
    try:
        out, err = process.communicate(timeout=timeout)
        return out + err, process.returncode
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        out, err = process.communicate()
        return out + err, "timeout"


def run_stage(place, stage: str, user: Path, work: Path) -> list[tuple[str, bool, str]]:
    """[(check, passed, detail)] of one stage, run in a fresh process of the place's bpy."""
    if stage == "blender_splats":  # its own script, its own fresh user folder (under --work)
        arguments = [place.inside(place.checks), "--zip", place.inside(place.zip), "--data",
                     place.inside(place.data / "splats"), "--work",
                     place.inside(work / "blender_splats")]
    else:
        arguments = [place.inside(place.script), "--inside", stage, "--zip",
                     place.inside(place.zip), "--work", place.inside(work), "--data",
                     place.inside(place.data)]
    command, env = place.command(arguments, user, work)
    output, code = run_process(command, env, work, timeout=900)
    (work / f"{stage}.log").write_text(output)
    results = []
    for line in output.splitlines():
        if line.startswith(("PASS ", "FAIL ")):
            name, _, detail = line[5:].partition(": ")
            results.append((name, line.startswith("PASS"), detail))
        elif line.startswith("COMPARE "):
            frame = json.loads(line[len("COMPARE "):])
            for key in ("png", "exr", "splats"):
                frame[key] = str(place.outside(frame[key]))
            try:
                results.append((frame["name"], True, compare_frame(frame)))
            except (AssertionError, OSError, ValueError) as error:
                results.append((frame["name"], False, " ".join(str(error).split())))
    if code != 0:
        tail = " | ".join(output.strip().splitlines()[-6:])
        results.append((f"{stage} (process)", False, f"exit {code}: {tail}"))
    return results


# The expected image, computed in the project venv (addon.core's native compositor;
# tests/standard_view.py: what the Standard view writes; OpenImageIO from requirements.txt): what
# the installed extension wrote must equal it, whatever that Blender's own modules can do.

def compare_frame(frame: dict) -> str:
    """Raises AssertionError unless the written PNG is the native composite within 1/255 and
    shows both the splats and the cube in front of them; else a summary."""
    import numpy as np

    sys.path.insert(0, str(ROOT / "tests"))
    from addon.core.cameras import BlenderCameraParams, camera_from_blender
    from addon.core.gaussians import Gaussians
    from addon.core.images import exr_layers as exr
    from standard_view import native_composite, read_png, standard_8bit

    channels = exr.read_channels(frame["exr"])
    mesh = exr.find_pass(channels, "ViewLayer", "Combined", "RGBA")
    depth = exr.find_pass(channels, "ViewLayer", "Depth", "Z")
    assert mesh is not None and depth is not None, \
        f"the EXR lacks the view layer's Combined or Depth pass: {sorted(channels)[:12]}"
    params = dict(frame["camera"], matrix_world=np.array(frame["camera"]["matrix_world"]))
    camera = camera_from_blender(BlenderCameraParams(**params))
    with np.load(frame["splats"]) as arrays:
        gaussians = Gaussians(**{k: arrays[k] for k in arrays.files})
    expected = standard_8bit(native_composite(gaussians, camera, mesh, depth[..., 0]))
    mesh_only = standard_8bit(mesh)
    written = read_png(Path(frame["png"]))
    error = np.abs(written - expected).max()
    splats_seen = np.abs(written[..., :3] - mesh_only[..., :3]).max()
    cube = (mesh_only[..., 0] > 150) & (mesh_only[..., 2] < 100)  # the orange cube's pixels
    assert error <= 1, (f"the written image differs from the native composite by {error}/255 "
                        f"(written values {written.min()}..{written.max()}, expected "
                        f"{expected.min()}..{expected.max()})")
    assert splats_seen > 20, "no splats in the written image"
    assert cube.sum() > 0 and np.abs(written[cube] - mesh_only[cube]).max() <= 1, \
        "the cube in front of the splats is missing or covered"
    return f"max error {error}/255, splats change pixels by up to {splats_seen}/255"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--bpy", action="append", help=f"(repeatable; default {BPY_VERSIONS})")
    parser.add_argument("--zip", help="test this zip instead of building one")
    parser.add_argument("--cache", default=str(default_cache()))
    parser.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    parser.add_argument("--keep", action="store_true", help="keep the work folders")
    parser.add_argument("--inside", choices=STAGES[:-1], help=argparse.SUPPRESS)
    parser.add_argument("--work", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.inside:
        return inside(args.inside, Path(args.zip), Path(args.work), Path(args.data))

    sys.path.insert(0, str(ROOT))  # the expected images come from this checkout's addon.core
    started = time.perf_counter()
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    data = Path(args.data).resolve()
    scratch = Path(tempfile.mkdtemp(prefix="installed-extension-"))
    zip_path = Path(args.zip).resolve() if args.zip else build_zip(scratch / "dist")
    print(f"zip: {zip_path} ({zip_path.stat().st_size / 1e6:.1f} MB)", flush=True)
    versions = args.bpy or list(BPY_VERSIONS)
    summary, seconds, logs, seen = [], {}, [], {}
    for version in versions:
        t0 = time.perf_counter()
        try:
            place = (InPy313Root(version, zip_path, data) if version_line(version) >= PY313_FROM
                     else HostVenv(version, cache, scratch, zip_path, data))
        except (RuntimeError, OSError, subprocess.CalledProcessError) as error:
            print(f"[bpy {version}] FAIL bpy {version} set up: {error}", flush=True)
            summary.append((version, "set up", False))
            continue
        user, work = place.base / "user", place.base / "work"
        work.mkdir(parents=True)
        for stage in stages_for(version):
            results = run_stage(place, stage, user, work)
            for name, passed, detail in results:
                print(f"[bpy {version}] {'PASS' if passed else 'FAIL'} {name}"
                      + (f": {detail}" if detail else ""), flush=True)
            for name, passed, _ in results:  # a name seen before gets its count
                seen[version, name] = seen.get((version, name), 0) + 1
                count = seen[version, name]
                summary.append((version, name + (f" ({count})" if count > 1 else ""), passed))
            if stage == "install" and not any(n == "install the zip" and p for n, p, _ in results):
                break  # nothing else can run without the extension
        seconds[version] = time.perf_counter() - t0
        logs.append(work)
        print(f"[bpy {version}] {seconds[version]:.0f} s (logs: {work})", flush=True)
    failed = [(v, n) for v, n, p in summary if not p]
    print()
    print(version_table(summary, versions, seconds))
    print(f"{len(summary) - len(failed)} passed, {len(failed)} failed in "
          f"{time.perf_counter() - started:.0f} s")
    for version, name in failed:
        print(f"  FAILED bpy {version}: {name}")
    if not args.keep and not failed:
        shutil.rmtree(scratch, ignore_errors=True)
        if InPy313Root.staged is not None:
            shutil.rmtree(InPy313Root.staged, ignore_errors=True)
    elif InPy313Root.staged is not None:
        print(f"py313 work folders kept in {InPy313Root.staged}")
    return 1 if failed or not summary else 0


def version_table(summary: list[tuple[str, str, bool]], versions: list[str],
                  seconds: dict[str, float]) -> str:
    """Every check (first-seen order) against every version: ok, FAIL, or - (not run there)."""
    names = list(dict.fromkeys(name for _, name, _ in summary))
    result = {(v, n): p for v, n, p in summary}
    width = max([len(n) for n in names] + [12])
    rows = [f"{'check':<{width}}  " + "  ".join(f"{v:>7}" for v in versions)]
    for name in names:
        cells = ["-" if (v, name) not in result else "ok" if result[v, name] else "FAIL"
                 for v in versions]
        rows.append(f"{name:<{width}}  " + "  ".join(f"{c:>7}" for c in cells))
    rows.append(f"{'seconds':<{width}}  " + "  ".join(
        f"{seconds[v]:>7.0f}" if v in seconds else f"{'-':>7}" for v in versions))
    return "\n".join(rows)


# ====================================================== inside a clean bpy venv (one stage)

def inside(stage: str, zip_path: Path, work: Path, data: Path) -> int:
    import bpy

    if stage == "install":
        stage_install(bpy, zip_path)
        return 0
    if bpy.app.version >= (4, 5):
        bpy.ops.wm.read_userpref()  # what Blender's startup does: enabled extensions load
    else:  # bpy 4.2.23 crashes in read_userpref (any user folder): enable it as in Preferences
        bpy.ops.preferences.addon_enable(module=EXTENSION)
    if EXTENSION not in bpy.context.preferences.addons:
        print(f"FAIL {stage}: the extension is not enabled after reading the preferences")
        return 1
    clear_scene(bpy)
    {"formats": stage_formats, "render": stage_render, "colmap": stage_colmap}[stage](
        bpy, work, data)
    return 0


def clear_scene(bpy) -> None:
    # Not factory settings: they would also switch the extension off. Hidden data (a name with
    # a leading dot: the add-on's compositor helper scene and its camera, which Blender 5.1+
    # gets as soon as a scene has splats) stays, as a user's deleting would leave it.
    for collection in (bpy.data.objects, bpy.data.meshes, bpy.data.materials, bpy.data.cameras,
                       bpy.data.lights, bpy.data.images, bpy.data.collections):
        for item in list(collection):
            if not item.name.startswith("."):
                collection.remove(item)


def new_scene_objects(bpy, before: set) -> list:
    """The objects made since `before` that the current scene shows (not the add-on's
    helper scene's)."""
    scene_objects = set(bpy.context.scene.objects)
    return [o for o in set(bpy.data.objects) - before if o in scene_objects]


def stage_install(bpy, zip_path: Path) -> None:
    user = os.environ["BLENDER_USER_RESOURCES"]
    with check("extension validate"):  # what `blender --command extension validate` runs
        cli = Path(bpy.utils.system_resource("SCRIPTS")) / "addons_core/bl_pkg/cli/blender_ext.py"
        done = subprocess.run([sys.executable, str(cli), "validate", str(zip_path)],
                              capture_output=True, text=True, timeout=120)
        output = " ".join((done.stdout + done.stderr).split())
        assert done.returncode == 0 and "FATAL" not in output and "Error" not in output, output
    install_zip(bpy, zip_path)
    for name in MODULES:
        with check(f"import {name}") as c:
            module = __import__(name)
            origin = Path(module.__file__)
            # splatcore exists only in the zip; bpy itself may have loaded zstandard already.
            assert name != "splatcore" or origin.is_relative_to(user), f"loaded from {origin}"
            c.detail = ("from the extension" if origin.is_relative_to(user) else
                        f"from {origin.parent}")
    bpy.ops.wm.save_userpref()


# ------------------------------------------------------------------------------ formats

FILES = (("playbot_125k_sh2.ply", 125_000), ("guitar.compressed.ply", 90_854),
         ("biker.spz", 152_746), ("chair.splat", 89_945),
         ("playbot_sog/lod-meta.json", 500_000))  # streamed SOG: WebP through OpenImageIO


def splat_count(obj) -> int:
    return ext("blender.splat_object").point_count(obj.data)


def import_file(bpy, path: Path):
    before = set(bpy.data.objects)
    result = bpy.ops.splat.import_splats(filepath=str(path))
    assert result == {"FINISHED"}, result
    (obj,) = new_scene_objects(bpy, before)
    return obj


def stage_formats(bpy, work: Path, data: Path) -> None:
    splats = data / "splats"
    chair = None
    for name, count in FILES:
        with check(f"import {name}") as c:
            obj = import_file(bpy, splats / name)
            assert splat_count(obj) == count, f"{splat_count(obj)} splats, expected {count}"
            c.detail = f"{count} splats"
            chair = obj if name.endswith(".splat") else chair
    registry = ext("core.formats.registry")
    suffixes = [f.endings[0] for f in registry.export_formats() if not f.whole_name]
    for suffix in suffixes:
        with check(f"export {suffix} and import it back") as c:
            assert chair is not None, "no object to export"
            bpy.context.view_layer.objects.active = chair
            target = work / f"exported{suffix}"
            result = bpy.ops.splat.export_splats(filepath=str(target))
            assert result == {"FINISHED"}, result
            back = import_file(bpy, target)
            assert splat_count(back) == splat_count(chair)
            c.detail = f"{target.stat().st_size / 1e6:.1f} MB"


# ------------------------------------------------------------------------------- render

WIDTH, HEIGHT = 64, 48


def material(bpy, name: str, colour, engine: str):
    return scene_kit.material(bpy, name, colour, emission=engine == "CYCLES")


def build_render_scene(bpy, data: Path, engine: str):
    """PLAYBOT, a cube in front of it, a plane behind it, a camera looking along +Y."""
    import math

    clear_scene(bpy)
    scene = bpy.context.scene
    splats = import_file(bpy, data / "splats" / "playbot_125k_sh2.ply")
    low, high, centre, radius = scene_kit.world_bounds(splats)
    bpy.ops.mesh.primitive_cube_add(size=0.35 * radius, location=(
        centre[0] + 0.25 * radius, low[1] - 0.4 * radius, centre[2]))
    cube = bpy.context.active_object
    cube.data.materials.append(material(bpy, "Cube", (0.9, 0.3, 0.1), engine))
    bpy.ops.mesh.primitive_plane_add(size=20 * radius, location=(
        centre[0], high[1] + 0.5 * radius, centre[2]), rotation=(math.pi / 2, 0, 0))
    bpy.context.active_object.data.materials.append(
        material(bpy, "Plane", (0.1, 0.35, 0.8), engine))
    scene_kit.camera_in_front(bpy, scene, centre, radius)
    render = scene.render
    render.resolution_x, render.resolution_y, render.resolution_percentage = WIDTH, HEIGHT, 100
    if engine == "CYCLES":
        scene_kit.flat_cycles(scene)
    else:
        scene.display.shading.color_type = "MATERIAL"
    render.engine = engine
    render.threads_mode, render.threads = "FIXED", 2
    scene_kit.standard_view(scene)
    return scene, cube


def output_png(bpy, scene, prefix: Path) -> None:
    scene_kit.png_8bit(scene.render.image_settings)
    scene.render.filepath = str(prefix)


def output_multilayer_exr(bpy, scene, prefix: Path) -> None:
    scene_kit.multilayer_exr(scene.render.image_settings)
    scene.render.filepath = str(prefix)


def dump_frame(bpy, scene, name: str, png: Path, exr_path: Path) -> None:
    """What the driver needs to compute the expected frame: the splats as the add-on gathers
    them from the depsgraph, Blender's camera, the written PNG and the multilayer EXR (Blender's
    own mesh colour and depth) of the same frame. Printed as a COMPARE line."""
    import numpy as np

    gather = ext("blender.sources.gather")
    depsgraph = bpy.context.evaluated_depsgraph_get()
    g = gather.gather(depsgraph).gaussians
    splats = png.with_suffix(".splats.npz")
    np.savez(splats, means=g.means, log_scales=g.log_scales, quats=g.quats,
             opacity_logits=g.opacity_logits, sh=g.sh)
    cam = scene.camera.evaluated_get(depsgraph)
    r = scene.render
    camera = dict(matrix_world=[list(row) for row in cam.matrix_world], lens=cam.data.lens,
                  sensor_width=cam.data.sensor_width, sensor_height=cam.data.sensor_height,
                  sensor_fit=cam.data.sensor_fit, shift_x=cam.data.shift_x,
                  shift_y=cam.data.shift_y, resolution_x=r.resolution_x,
                  resolution_y=r.resolution_y, resolution_percentage=r.resolution_percentage,
                  pixel_aspect_x=r.pixel_aspect_x, pixel_aspect_y=r.pixel_aspect_y)
    print("COMPARE " + json.dumps(dict(name=name, png=str(png), exr=str(exr_path),
                                       splats=str(splats), camera=camera)), flush=True)


def stage_render(bpy, work: Path, data: Path) -> None:
    """Renders; the driver compares (COMPARE lines), independently of this Blender's modules."""
    for engine in ("CYCLES", "BLENDER_WORKBENCH"):
        name = f"F12 {engine.split('_')[-1].title()} with meshes"
        with check(f"{name} (the render call)"):
            scene, _ = build_render_scene(bpy, data, engine)
            output_png(bpy, scene, work / f"f12_{engine}")
            result = bpy.ops.render.render(write_still=True)
            assert result == {"FINISHED"}, result
            output_multilayer_exr(bpy, scene, work / f"f12_{engine}_layers")
            assert bpy.ops.render.render(write_still=True) == {"FINISHED"}
            dump_frame(bpy, scene, name, work / f"f12_{engine}.png",
                       work / f"f12_{engine}_layers.exr")
    with check("animation (render -a), Workbench, 2 frames (the render calls)") as c:
        scene, cube = build_render_scene(bpy, data, "BLENDER_WORKBENCH")
        scene.frame_start, scene.frame_end = 1, 2
        x = cube.location.x
        for frame, dx in ((1, -0.3), (2, 0.3)):
            cube.location.x = x + dx
            cube.keyframe_insert("location", frame=frame)
        output_png(bpy, scene, work / "anim_")
        assert bpy.ops.render.render(animation=True) == {"FINISHED"}
        output_multilayer_exr(bpy, scene, work / "anim_layers_")
        assert bpy.ops.render.render(animation=True) == {"FINISHED"}
        for frame in (1, 2):
            scene.frame_set(frame)
            dump_frame(bpy, scene, f"animation frame {frame}", work / f"anim_{frame:04d}.png",
                       work / f"anim_layers_{frame:04d}.exr")
        c.detail = "frames 1-2"


# ------------------------------------------------------------------------------- colmap

def stage_colmap(bpy, work: Path, data: Path) -> None:
    trained = None
    collection = None
    with check("Import Photos or Video: 16 of cup's photos reconstructed and imported") as c:
        photos = work / "photos"
        photos.mkdir(exist_ok=True)
        for number in range(1, 17):
            shutil.copy(data / "cup" / "images" / f"{number}.jpg", photos)
        before = set(bpy.data.collections)
        result = bpy.ops.splat.import_photos(filepath=str(photos) + "/", threads=2,
                                             output=str(work / "photos_scene"))
        assert result == {"FINISHED"}, result
        (made,) = set(bpy.data.collections) - before
        cameras = [o for o in made.all_objects if "colmap_image_name" in o]
        assert len(cameras) >= 12, f"{len(cameras)} cameras placed of 16"
        c.detail = f"{len(cameras)} of 16 photos placed"
        bpy.data.collections.remove(made)
    with check("COLMAP import of a distorted model (beer, SIMPLE_RADIAL, images_8)") as c:
        before = set(bpy.data.collections)
        result = bpy.ops.splat.import_colmap(directory=str(data / "beer"),
                                             image_folder="images_8",
                                             cache_dir=str(work / "colmap-cache"))
        assert result == {"FINISHED"}, result
        (collection,) = set(bpy.data.collections) - before
        cameras = [o for o in collection.all_objects if "colmap_image_name" in o]
        assert len(cameras) == 71, f"{len(cameras)} cameras, expected 71"
        c.detail = f"{len(cameras)} cameras into '{collection.name}'"
    with check("training (100 steps)") as c:
        assert collection is not None, "nothing imported to train"
        before = set(bpy.data.objects)
        result = bpy.ops.splat.train(collection=collection.name, steps=100,
                                     max_gaussians=20_000, sh_degree=1, threads=2,
                                     update_every=0, checkpoint_every=0,
                                     checkpoint=str(work / "train.ckpt"))
        assert result == {"FINISHED"}, result
        new = [o for o in new_scene_objects(bpy, before) if splat_count_or_none(o)]
        assert len(new) == 1, f"{len(new)} new splat objects"
        trained = new[0]
        assert trained.get("splat_trained_steps") == 100, dict(trained.items())
        c.detail = (f"{splat_count(trained)} splats, held-out PSNR "
                    f"{trained.get('splat_heldout_psnr', float('nan')):.1f} dB")
    with check("Convert to Mesh") as c:
        assert trained is not None, "nothing trained to convert"
        for obj in bpy.context.view_layer.objects:
            obj.select_set(False)
        bpy.context.view_layer.objects.active = trained
        trained.select_set(True)
        result = bpy.ops.splat.convert_to_mesh(resolution=32, max_triangles=2000,
                                               texture_size=64, view_count=8, view_size=48)
        assert result == {"FINISHED"}, result
        mesh_obj = bpy.context.view_layer.objects.active
        assert mesh_obj is not trained and mesh_obj.type == "MESH"
        mesh = mesh_obj.data
        assert len(mesh.polygons) > 0 and "UVMap" in mesh.uv_layers
        images = [n.image for n in mesh.materials[0].node_tree.nodes if n.type == "TEX_IMAGE"]
        assert images and images[0].size[:] == (64, 64)
        c.detail = f"{len(mesh.polygons)} triangles, 64 px texture"
    with check("export the trained splats") as c:
        assert trained is not None, "nothing trained to export"
        bpy.context.view_layer.objects.active = trained
        target = work / "trained.ply"
        assert bpy.ops.splat.export_splats(filepath=str(target)) == {"FINISHED"}
        back = import_file(bpy, target)
        assert splat_count(back) == splat_count(trained)
        c.detail = f"{target.stat().st_size / 1e6:.2f} MB"


def splat_count_or_none(obj):
    splat_object = ext("blender.splat_object")
    return splat_object.is_splat_object(obj) and splat_object.point_count(obj.data)


if __name__ == "__main__":
    sys.exit(main())
