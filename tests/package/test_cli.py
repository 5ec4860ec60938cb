"""The command line (`addon.cli`): every verb's --help, and a small run of each from the venv
(`python -m addon <verb>`, a fresh process each, as a user or a farm runs it)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from addon import cli
from addon.core import axes, splat_io
from addon.core.images import files
from addon.core.transform import transform_gaussians

ROOT = Path(__file__).resolve().parents[2]
VERBS = ("reconstruct", "import-colmap", "train", "render", "export", "convert-to-mesh",
         "convert")


def run(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    result = subprocess.run([sys.executable, "-m", "addon", *args], cwd=ROOT, text=True,
                            capture_output=True, timeout=timeout)
    print(result.stdout[-3000:], result.stderr[-3000:])
    return result


def test_the_parser_knows_every_verb():
    parser = cli.build_parser("test")
    choices = next(a for a in parser._actions if a.dest == "verb").choices  # noqa: SLF001
    assert tuple(choices) == VERBS


@pytest.mark.parametrize("verb", VERBS)
def test_every_verb_has_help(verb, capsys):
    assert cli.main([verb, "--help"], prog="blender -c gaussian_splatting") == 0
    text = capsys.readouterr().out
    assert text.startswith(f"usage: blender -c gaussian_splatting {verb}")
    assert "--help" in text


def test_help_from_the_venv_needs_no_blender():
    result = run("--help")
    assert result.returncode == 0 and all(verb in result.stdout for verb in VERBS)
    probe = subprocess.run([sys.executable, "-c", "import sys; from addon import cli; "
                            "cli.main(['convert', '--help']); print('bpy' in sys.modules)"],
                           cwd=ROOT, text=True, capture_output=True, timeout=60)
    assert probe.stdout.strip().endswith("False")


def test_bad_arguments_and_bad_input_are_clear(tmp_path, capsys):
    assert cli.main(["convert", str(tmp_path / "none.ply"), str(tmp_path / "out.ply")]) == 1
    assert "none.ply" in capsys.readouterr().err
    assert cli.main(["convert", "a.ply", "b.ply", "--up", "W"]) == 2
    assert cli.main(["render", "x.blend", "--frames", "5-2"]) == 2
    assert cli.main(["export", "x.blend", "--out", "rig.txt"]) == 2
    assert "rig.txt" in capsys.readouterr().err
    assert cli.main(["export", "x.ply", "--out", "rig.ply"]) == 2
    assert "expected a .blend" in capsys.readouterr().err
    assert cli.main(["nonsense"]) == 2


def test_reconstruct_prints_what_it_placed_and_needs_no_blender(tmp_path):
    photos = tmp_path / "photos"
    photos.mkdir()
    for i in range(10):
        (photos / f"{i:03d}.jpg").write_bytes(
            (ROOT / "examples" / "demo_colmap" / "images" / f"{i:03d}.jpg").read_bytes())
    (photos / "notes.txt").write_text("x")
    result = run("reconstruct", str(photos), "--out", str(tmp_path / "scene"), "--threads", "2")
    assert result.returncode == 0
    assert "Reconstructing: finding features" in result.stdout
    assert "registered " in result.stdout and "of 10 photos" in result.stdout
    assert "skipped notes.txt: not a JPEG, PNG or TIFF photo" in result.stdout
    probe = subprocess.run([sys.executable, "-c", "import sys; from addon import cli; "
                            f"cli.main(['reconstruct', {str(photos)!r}, '--out', "
                            f"{str(tmp_path / 'scene')!r}]); print('bpy' in sys.modules)"],
                           cwd=ROOT, text=True, capture_output=True, timeout=120)
    assert probe.stdout.strip().endswith("False")  # and all taken from the cache
    bad = run("reconstruct", str(tmp_path / "nowhere"), "--out", str(tmp_path / "x"))
    assert bad.returncode == 1 and "no such folder or video file" in bad.stderr
    assert run("reconstruct", str(photos), "--out", "x", "--matching", "magic").returncode == 2


def test_convert_keeps_the_frame_by_default_and_turns_it_with_axes(rng, tmp_path):
    from scenes import random_gaussians

    source = tmp_path / "in.ply"
    g = random_gaussians(rng, 100, 3)
    splat_io.save(g, source)
    assert run("convert", str(source), str(tmp_path / "same.ply")).returncode == 0
    assert (tmp_path / "same.ply").read_bytes() == source.read_bytes()
    # file in Blender's frame (forward Y, up Z) -> the 3DGS frame of the output (auto)
    assert cli.main(["convert", str(source), str(tmp_path / "turned.ply"), "--forward", "Y",
                     "--up", "Z"]) == 0
    expected = transform_gaussians(g, np.linalg.inv(axes.axis_matrix4("Z", "-Y")))
    turned = splat_io.load(tmp_path / "turned.ply")
    assert np.array_equal(turned.means, expected.means)
    assert np.allclose(turned.sh, expected.sh, atol=1e-6)
    assert cli.main(["convert", str(source), str(tmp_path / "x.spz"), "--up", "-Y"]) == 0
    assert len(splat_io.load(tmp_path / "x.spz")) == 100


def test_import_train_render_and_mesh_from_the_venv(tmp_path):
    scene = tmp_path / "scene.blend"
    result = run("import-colmap", "examples/demo_colmap", "--out", str(scene))
    assert result.returncode == 0 and scene.is_file(), result.stderr
    assert "Importing COLMAP: reading" in result.stdout  # a line per stage, headless

    trained = tmp_path / "trained.blend"
    # --max-width 120: the 480x360 photos at 120x90, as --downscale 4 makes them for the resume
    result = run("train", str(scene), "--out", str(trained), "--steps", "20", "--max-width", "120",
                 "--max-gaussians", "2000", "--checkpoint", str(tmp_path / "state.npz"))
    assert result.returncode == 0 and trained.is_file(), result.stderr
    assert "Training step 20 of 20 (100 %)" in result.stdout
    splats = tmp_path / "trained.ply"
    result = run("train", str(trained), "--out", str(splats), "--steps", "25", "--resume",
                 "--downscale", "4", "--checkpoint", str(tmp_path / "state.npz"))
    assert result.returncode == 0 and len(splat_io.load(splats)) > 0, result.stderr
    assert "Training step 20 of 25 (80 %)" in result.stdout  # a resume starts where it stopped

    result = run("render", str(trained), "--frames", "1-2", "--engine", "SPLAT_GAUSSIANS",
                 "--out", str(tmp_path / "frame_"))
    assert result.returncode == 0, result.stderr
    for frame in (1, 2):
        header = files.read_header(tmp_path / f"frame_{frame:04d}.png")
        assert header.size(False) == (480, 360)  # the first COLMAP camera's photo size

    mesh = tmp_path / "mesh.blend"
    result = run("convert-to-mesh", str(splats), "--out", str(mesh), "--resolution", "24",
                 "--max-triangles", "500", "--texture-size", "32", "--view-count", "6",
                 "--view-size", "32", "--cameras", "sphere")
    assert result.returncode == 0 and mesh.is_file(), result.stderr
    assert "Converting to mesh: texture" in result.stdout


def test_blender_command_is_registered_with_the_add_on():
    import bpy_support as bs

    bs.ensure_registered()
    from addon import cli_command

    import bpy
    assert cli_command.is_registered() == hasattr(bpy.utils, "register_cli_command")


def test_render_gives_each_frame_its_marker_cameras_size(tmp_path, rng):
    """Portrait and landscape COLMAP cameras switched by markers: frame by frame, each image has
    its own photo's size (a single animation render cannot change size)."""
    import bpy_support as bs
    from bpy_support import bpy
    from colmap_helpers import synthetic_workspace

    cameras = [("PINHOLE", 80, 60, [70.0, 61.0, 40.0, 30.0]),
               ("PINHOLE", 48, 72, [50.0, 58.5, 24.0, 36.0])]
    synthetic_workspace(tmp_path / "mixed", cameras, [("a.png", 0), ("b.png", 1), ("c.png", 0)],
                        rng=rng, n_points=60)
    scene_file = tmp_path / "mixed.blend"
    assert cli.main(["import-colmap", str(tmp_path / "mixed"), "--out", str(scene_file),
                     "--no-align"]) == 0
    scene = bpy.context.scene
    for frame, name in enumerate(("a.png", "b.png"), start=1):
        scene.timeline_markers.new(name, frame=frame).camera = bpy.data.objects[name]
    scene.render.engine = "SPLAT_GAUSSIANS"
    bpy.ops.wm.save_as_mainfile(filepath=str(scene_file))
    bs.reset_scene()
    result = run("render", str(scene_file), "--frames", "1-2", "--out", str(tmp_path / "f_"))
    assert result.returncode == 0, result.stderr
    assert files.read_header(tmp_path / "f_0001.png").size(False) == (80, 60)
    assert files.read_header(tmp_path / "f_0002.png").size(False) == (48, 72)


def test_train_leaves_the_training_defaults_to_the_operator():
    parser = cli.build_parser("test")
    args = parser.parse_args(["train", "scene", "--out", "out.ply"])
    names = ("steps", "max_gaussians", "strategy", "sh_degree", "compact")
    assert cli._options(args, names) == {}  # noqa: SLF001 (until done, auto, compacted)
    args = parser.parse_args(["train", "scene", "--out", "out.ply", "--steps", "7000",
                              "--strategy", "default", "--no-compact"])
    assert cli._options(args, names) == {"steps": 7000, "strategy": "default",  # noqa: SLF001
                                         "compact": False}
    assert cli.main(["train", "scene", "--out", "o.ply", "--strategy", "nope"]) == 2


@pytest.mark.parametrize("argv", [
    ["convert", "a.ply", "b.xyz"],                        # no format writes .xyz
    ["convert", "a.ply", "b"],                            # no extension
    ["train", "folder", "--out", "splats.txt"],
    ["import-colmap", "folder", "--out", "scene.ply"],    # a .blend is what it writes
    ["convert-to-mesh", "in.ply", "--out", "mesh.obj"],
])
def test_an_output_name_the_verb_cannot_write_is_a_bad_argument(argv, capsys):
    """Exit 2 (bad arguments), before any work: nothing is read, Blender is not started."""
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("error:") == 1 and argv[-1] in err


def test_python_m_addon_works_from_any_folder_with_the_repository_on_the_path(tmp_path):
    """From another folder, `python -m addon` finds the package once the repository is on the
    path (what scripts/bootstrap.sh's .pth file does for the venv; here PYTHONPATH)."""
    import os

    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    result = subprocess.run([sys.executable, "-m", "addon", "convert", "--help"], cwd=tmp_path,
                            text=True, capture_output=True, timeout=60, env=env)
    assert result.returncode == 0 and "usage:" in result.stdout, result.stderr


def test_an_operator_error_is_printed_once(tmp_path):
    """Blender writes an operator's error report to stdout and raises it: the command prints
    it once, on stderr."""
    (tmp_path / "sparse").mkdir()
    result = run("import-colmap", str(tmp_path), "--out", str(tmp_path / "x.blend"))
    assert result.returncode == 1
    both = result.stdout + result.stderr
    assert "error:" in result.stderr
    line = result.stderr.strip().splitlines()[-1].split("error: ", 1)[1]
    assert both.count(line[:60]) == 1, both


def test_an_unknown_render_engine_is_a_bad_argument(tmp_path):
    scene = tmp_path / "empty.blend"
    made = subprocess.run([sys.executable, "-c", "import bpy, sys; bpy.ops.wm.read_homefile("
                           "use_empty=True); bpy.ops.wm.save_as_mainfile(filepath=sys.argv[1])",
                           str(scene)], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert made.returncode == 0, made.stderr
    result = run("render", str(scene), "--engine", "NO_SUCH_ENGINE", "--out", str(tmp_path / "f_"))
    assert result.returncode == 2 and "NO_SUCH_ENGINE" in result.stderr
    assert "CYCLES" in result.stderr  # what there is
