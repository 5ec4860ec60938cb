"""Splat sequences in Blender (bpy): one object whose Gaussians are the frame's file, through
frame changes, gather, F12 animation renders, export back, with bounded memory."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import bpy_support as bs
from bpy_support import bpy  # the shared bpy import
import numpy as np
import pytest

from addon.blender.io import operators, sequence
from addon.core import splat_io
from addon.core.formats import registry
from addon.core.render.renderer import render
from addon.core.transform import covariances
from scenes import random_gaussians
from standard_view import read_png

ROOT = Path(__file__).resolve().parents[3]
COUNTS = {1: 120, 2: 200, 3: 60}  # frame number -> Gaussians in its file


@pytest.fixture(autouse=True)
def empty_scene():
    bs.reset_scene()
    yield
    sequence.forget_all()


def write_frames(folder: Path, counts: dict[int, int], *, degree: int = 1) -> dict[int, Path]:
    rng = np.random.default_rng(7)
    files = {}
    for number, count in counts.items():
        g = random_gaussians(rng, count, degree, radius=1.0, stray=0.0)
        g.means[:, 0] += 0.4 * (number - 2)  # each frame somewhere else: different images
        files[number] = folder / f"walk_{number:04d}.ply"
        splat_io.save(g, files[number])
    return files


def file_gaussians(path: Path):
    return registry.read(path)[0]


def test_each_frame_shows_its_file_bit_exact(tmp_path):
    files = write_frames(tmp_path, COUNTS)
    scene = bpy.context.scene
    scene.frame_set(2)
    obj = operators.import_sequence(files[1])
    assert obj.splat.sequence_source == str(files[1]) and obj.name == "walk"
    assert bs.gaussians_equal(bs.mesh_gaussians(obj), file_gaussians(files[2]))  # frame 2 now
    assert len(bpy.data.objects) == 1
    for frame in (1, 3, 2, 1):
        scene.frame_set(frame)
        assert bs.gaussians_equal(bs.mesh_gaussians(obj), file_gaussians(files[frame])), frame
        gathered = bs.gather.gather(bpy.context.evaluated_depsgraph_get())  # cached path
        assert len(gathered.gaussians) == COUNTS[frame]
    scene.frame_set(10)  # after the last file: the last one holds
    assert len(obj.data.vertices) == COUNTS[3]
    obj.splat.sequence_frame_offset = 1  # scene frame 1 shows file 2
    scene.frame_set(1)
    assert bs.gaussians_equal(bs.mesh_gaussians(obj), file_gaussians(files[2]))


def test_the_operator_imports_one_object_and_reports_bad_sequences(tmp_path):
    files = write_frames(tmp_path, COUNTS)
    assert bpy.ops.splat.import_splats(filepath=str(files[2]), sequence=True) == {"FINISHED"}
    (obj,) = bpy.data.objects
    assert obj.splat.sequence_source and bpy.context.view_layer.objects.active == obj
    before = bs.scene_state()
    with pytest.raises(RuntimeError, match="no files match"):
        bpy.ops.splat.import_splats(filepath=str(tmp_path / "none_####.ply"), sequence=True)
    assert bs.scene_state() == before


def test_edit_mode_is_left_alone(tmp_path):
    files = write_frames(tmp_path, COUNTS)
    scene = bpy.context.scene
    scene.frame_set(1)
    obj = operators.import_sequence(files[1])
    bpy.ops.object.mode_set(mode="EDIT")
    scene.frame_set(2)
    bpy.ops.object.mode_set(mode="OBJECT")
    assert len(obj.data.vertices) == COUNTS[1]
    scene.frame_set(3)
    assert len(obj.data.vertices) == COUNTS[3]


def test_a_bad_frame_keeps_the_previous_splats(tmp_path, capfd):
    files = write_frames(tmp_path, COUNTS)
    files[2].write_bytes(b"ply\nformat nonsense\n")
    scene = bpy.context.scene
    scene.frame_set(1)
    obj = operators.import_sequence(files[1])
    scene.frame_set(2)
    assert len(obj.data.vertices) == COUNTS[1]
    assert "walk_0002.ply" in capfd.readouterr().err
    scene.frame_set(3)
    assert len(obj.data.vertices) == COUNTS[3]


def _animation_scene(tmp_path, files):
    scene = bpy.context.scene
    scene.frame_set(1)
    operators.import_sequence(files[1])
    camera = bs.add_camera(location=(0.0, -6.0, 0.0), rotation=(math.pi / 2, 0, 0), lens=35,
                           width=32, height=24)
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.render.film_transparent = True
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    settings = scene.render.image_settings
    settings.media_type, settings.file_format, settings.color_mode = "IMAGE", "PNG", "RGBA"
    settings.color_depth = "8"
    scene.frame_start, scene.frame_end = 1, 3
    scene.render.filepath = str(tmp_path / "anim_")
    return scene, camera


def test_animation_render_gives_each_frames_image(tmp_path):
    """F12 animation (Workbench): frame F's PNG is the reference render of file F's splats."""
    files = write_frames(tmp_path, COUNTS)
    scene, camera = _animation_scene(tmp_path, files)
    assert bpy.ops.render.render(animation=True) == {"FINISHED"}
    images = []
    for frame in (1, 2, 3):
        written = read_png(tmp_path / f"anim_{frame:04d}.png")
        scene.frame_set(frame)
        depsgraph = bpy.context.evaluated_depsgraph_get()
        gathered = bs.gather.gather(depsgraph, use_cache=False).gaussians
        assert len(gathered) == COUNTS[frame]
        reference = render(gathered, bs.camera_of(camera, depsgraph))
        assert np.abs(written[..., 3] - np.round(reference.alpha * 255)).max() <= 1, frame
        images.append(written)
    assert all(np.abs(images[k] - images[k - 1]).max() > 20 for k in (1, 2))


def test_export_round_trip(tmp_path):
    files = write_frames(tmp_path, COUNTS)
    scene = bpy.context.scene
    scene.frame_set(2)
    obj = operators.import_sequence(tmp_path / "walk_####.ply")
    out = tmp_path / "out"
    out.mkdir()
    written = operators.export_sequence(obj, out / "copy_####.ply", [1, 2, 3])
    assert written == [out / f"copy_{n:04d}.ply" for n in (1, 2, 3)]
    assert scene.frame_current == 2
    for number in (1, 2, 3):
        assert bs.gaussians_equal(file_gaussians(written[number - 1]), file_gaussians(files[number]))
    scene.frame_start, scene.frame_end = 1, 3
    with bpy.context.temp_override(active_object=obj, object=obj):
        assert bpy.ops.splat.export_splats(filepath=str(out / "op.ply"), sequence=True) \
            == {"FINISHED"}
    for number in (1, 2, 3):
        assert bs.gaussians_equal(file_gaussians(out / f"op_{number:04d}.ply"),
                                  file_gaussians(files[number]))


def test_memory_stays_bounded_and_scrubbing_back_reads_nothing(tmp_path):
    write_frames(tmp_path, {n: 10 + n for n in range(1, 21)}, degree=0)
    scene = bpy.context.scene
    scene.frame_set(1)
    obj = operators.import_sequence(tmp_path)  # a folder
    frames = sequence.sequence_of(obj)
    assert len(frames) == 20 and frames.reads == 1
    for frame in range(1, 21):
        scene.frame_set(frame)
        assert len(obj.data.vertices) == 10 + frame
        assert len(frames.cached_numbers()) <= sequence.CACHE_FRAMES
    assert frames.reads == 20 and frames.cached_numbers() == [18, 19, 20]
    for frame in (19, 18, 20, 19, 18, 19, 20):  # scrubbing back over cached frames
        scene.frame_set(frame)
        assert len(obj.data.vertices) == 10 + frame
    assert frames.reads == 20
    assert sequence.loaded_sequences() == 1


def test_frames_of_the_same_count_gather_their_own_splats(tmp_path):
    files = write_frames(tmp_path, {1: 50, 2: 50})
    scene = bpy.context.scene
    scene.frame_set(1)
    obj = operators.import_sequence(files[1])
    for frame in (1, 2, 1, 2):
        scene.frame_set(frame)
        gathered = bs.gather.gather(bpy.context.evaluated_depsgraph_get()).gaussians
        matrix = np.array(obj.matrix_world, dtype=np.float64)
        expected = file_gaussians(files[frame]).means @ matrix[:3, :3].T + matrix[:3, 3]
        assert np.allclose(gathered.means, expected, atol=1e-5), frame


def test_a_frame_that_cannot_be_read_fails_the_render_not_shows_stale_splats(tmp_path):
    files = write_frames(tmp_path, COUNTS)
    scene, _camera = _animation_scene(tmp_path, files)
    files[2].write_bytes(b"ply\nformat nonsense\n")
    try:
        bpy.ops.render.render(animation=True)
    except RuntimeError:
        pass  # the render failed, as it must
    assert not (tmp_path / "anim_0002.png").exists()  # never frame 1's splats under frame 2


def test_a_frame_file_missing_on_another_machine_fails_that_frame(tmp_path):
    """A render farm worker whose copy of the sequence lacks a file that was there at import:
    that frame fails with a message naming the file, never shows the previous file's splats;
    a gap the sequence had at import still holds the previous file."""
    files = write_frames(tmp_path, COUNTS)
    scene, _camera = _animation_scene(tmp_path, files)
    obj = next(o for o in scene.objects if sequence.source_of(o))
    assert sequence.recorded_numbers(obj) == {1, 2, 3} and obj[sequence.NUMBERS_KEY] == "1-3"
    files[2].unlink()
    sequence.forget_all()                       # a fresh worker process: the folder read again
    try:
        bpy.ops.render.render(animation=True)
    except RuntimeError:
        pass
    from addon.blender.render import failures
    assert any("walk_0002.ply" in e and "missing" in e for e in failures.last_errors())
    assert not (tmp_path / "anim_0002.png").exists()
    # The same folder as imported with the gap: frame 2 holds frame 1, as image sequences do.
    sequence.record_numbers(obj, [1, 3])
    sequence.forget_all()
    assert bpy.ops.render.render(animation=True) == {"FINISHED"}
    assert np.array_equal(read_png(tmp_path / "anim_0002.png"), read_png(tmp_path / "anim_0001.png"))


def test_recorded_numbers_round_trip():
    obj = bpy.data.objects.new("o", None)
    sequence.record_numbers(obj, [5, 1, 2, 3, 9, 10, 7])
    assert obj[sequence.NUMBERS_KEY] == "1-3,5,7,9-10"
    assert sequence.recorded_numbers(obj) == {1, 2, 3, 5, 7, 9, 10}


def test_the_import_stores_the_path_relative_to_the_saved_blend(tmp_path):
    """What a render farm needs: `//frames/walk_####.ply` resolves wherever the .blend and its
    folder are mounted. The operator's Relative Path is on by default; an unsaved file keeps
    the absolute path."""
    (tmp_path / "frames").mkdir()
    files = write_frames(tmp_path / "frames", COUNTS)
    unsaved = operators.import_sequence(files[1], relative=True)
    assert unsaved.splat.sequence_source == str(files[1])
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))
    assert bpy.ops.splat.import_splats(filepath=str(files[1]), sequence=True) == {"FINISHED"}
    obj = bpy.context.active_object
    assert obj.splat.sequence_source == "//frames/walk_0001.ply"
    assert sequence.source_of(obj) == str(files[1])
    bpy.context.scene.frame_set(3)
    assert len(obj.data.vertices) == COUNTS[3]


def test_a_deformed_animation_exports_as_a_sequence_that_comes_back(rng, tmp_path):
    """A splat object bent by a keyframed Simple Deform (issue 35: shapes and SH follow the
    deformation) exported over a frame range, one file per frame, and imported back as a
    sequence: at each frame the imported object gathers the Gaussians the deformed one
    gathered (float32 rounding of the files' axis conversion), and the frames differ. The
    command line's `export --frames` writes the same files from the saved .blend."""
    g = random_gaussians(rng, 300, 1, radius=1.0, stray=0.0)
    obj = bs.splat_object.create_splat_object(g, "Bent")
    bend = obj.modifiers.new("Bend", "SIMPLE_DEFORM")
    bend.deform_method, bend.deform_axis = "BEND", "Z"
    for frame, angle in ((2, 0.3), (4, 1.5)):
        bend.angle = angle
        bend.keyframe_insert("angle", frame=frame)
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 10
    scene.frame_set(7)
    out = tmp_path / "out"
    out.mkdir()
    with bpy.context.temp_override(active_object=obj, object=obj):
        assert bpy.ops.splat.export_splats(filepath=str(out / "bent.ply"), sequence=True,
                                           use_scene_range=False, frame_start=2,
                                           frame_end=4) == {"FINISHED"}
    assert sorted(p.name for p in out.iterdir()) == [f"bent_{n:04d}.ply" for n in (2, 3, 4)]
    assert scene.frame_current == 7
    # the command line writes the same files from the saved .blend
    blend = tmp_path / "rig.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    result = subprocess.run([sys.executable, "-m", "addon", "export", str(blend), "--object",
                             "Bent", "--out", str(tmp_path / "cli.ply"), "--frames", "2-4"],
                            capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert result.returncode == 0, result.stderr
    for n in (2, 3, 4):
        assert bs.gaussians_equal(file_gaussians(tmp_path / f"cli_{n:04d}.ply"),
                                  file_gaussians(out / f"bent_{n:04d}.ply")), n
    gathered = {}
    for frame in (2, 3, 4):
        scene.frame_set(frame)
        gathered[frame] = bs.gather.gather(bpy.context.evaluated_depsgraph_get(), objects=[obj],
                                           use_cache=False, all_sh_bands=True).gaussians
    assert np.abs(gathered[4].quats - gathered[2].quats).max() > 0.1  # the shapes turned
    back = operators.import_sequence(out / "bent_####.ply")
    obj.hide_set(True)
    for frame in (2, 3, 4):
        scene.frame_set(frame)
        got = bs.gather.gather(bpy.context.evaluated_depsgraph_get(), objects=[back],
                               use_cache=False, all_sh_bands=True).gaussians
        want = gathered[frame]
        assert len(got) == len(want) == len(g)
        for name in ("means", "opacity_logits", "sh"):
            assert np.abs(getattr(got, name) - getattr(want, name)).max() <= 2e-6, (frame, name)
        # the shapes as covariances: a quaternion and log-scales are one of several spellings
        cov, cov_want = covariances(got), covariances(want)
        scale = np.abs(cov_want).max(axis=(1, 2), keepdims=True)
        assert (np.abs(cov - cov_want) / scale).max() <= 1e-5, frame
