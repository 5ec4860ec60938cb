"""Splat objects in Blender (bpy): attributes, import/export, gather, transforms, editing, files.

Renders use tiny images (64x48) and a few hundred Gaussians. "Invariance" compares a render of
the scene with the render after moving the splat object and the camera together (rotation,
translation, uniform scale); the tolerances are those of tests/core/test_transform.py (float rounding,
plus rare threshold flips), and the errors seen are printed and recorded as test properties.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import bpy_support as bs
from bpy_support import bpy  # the shared bpy import
import mathutils
import numpy as np
import pytest

from addon.blender import splat_object
from addon.blender.sources import gather
from addon.blender.io import operators
from addon.core import splat_io
from addon.core.gaussians import Gaussians
from addon.core.render.renderer import render
from addon.core.transform import covariances, transform_gaussians
from scenes import random_gaussians
from checks import compare_renders

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(autouse=True)
def empty_scene():
    bs.reset_scene()
    yield
    gather.clear_cache()


def make_object(g: Gaussians, name: str = "Splats", **options):
    obj = splat_object.create_splat_object(g, name, **options)
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    return obj


def depsgraph():
    return bpy.context.evaluated_depsgraph_get()


def gathered(**kwargs) -> gather.GatherResult:
    return gather.gather(depsgraph(), **kwargs)


def similarity_matrix(rng) -> mathutils.Matrix:
    q = rng.normal(size=4)
    rotation = mathutils.Quaternion(q / np.linalg.norm(q)).to_matrix().to_4x4()
    scale = float(np.exp(rng.uniform(np.log(0.3), np.log(3.0))))
    translation = mathutils.Matrix.Translation(rng.normal(scale=2.0, size=3).tolist())
    return translation @ rotation @ mathutils.Matrix.Scale(scale, 4)


def as_np(matrix) -> np.ndarray:
    return np.array(matrix, dtype=np.float64)


# ---------------------------------------------------------------------------- attributes

@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_gaussians_to_object_to_gaussians_is_bit_exact(rng, degree):
    g = random_gaussians(rng, 257, degree)
    g.quats[:3] = 0.0                       # zero quaternions (identity) stay zero
    g.quats[3:6] *= 1e3                     # unnormalised ones keep their length
    g.opacity_logits[:2] = (-1e30, 1e30)    # extreme but finite values pass through
    g.sh.view(np.uint32)[0, 0, 0] = 0x80000000  # -0.0 keeps its sign bit
    obj = make_object(g)
    assert splat_object.data_sh_degree(obj.data) == degree
    assert bs.gaussians_equal(bs.mesh_gaussians(obj), g)
    assert bs.gaussians_equal(gathered().gaussians, g)  # identity transform: nothing touched


def test_attribute_layout_is_as_documented(rng):
    obj = make_object(random_gaussians(rng, 10, 3))
    attributes = {a.name: (a.data_type, a.domain) for a in obj.data.attributes}
    assert attributes["position"] == ("FLOAT_VECTOR", "POINT")
    assert attributes["rotation"] == ("QUATERNION", "POINT")
    assert attributes["log_scale"] == ("FLOAT_VECTOR", "POINT")
    assert attributes["opacity_logit"] == ("FLOAT", "POINT")
    for k in range(16):
        assert attributes[f"sh_{k}"] == ("FLOAT_VECTOR", "POINT")
    assert obj.splat.is_splat and obj.splat.sh_degree == 3
    assert len(obj.data.edges) == 0 and len(obj.data.polygons) == 0
    obj.data.attributes.remove(obj.data.attributes["log_scale"])
    assert splat_object.missing_attributes(obj.data) == ["log_scale"]
    with pytest.raises(splat_object.SplatDataError, match="log_scale"):
        splat_object.gaussians_from_data(obj.data)
    assert gathered().batches == []  # no longer splats: not rendered


# --------------------------------------------------------------------------- import/export

def test_import_operator_creates_active_object(rng, tmp_path):
    g = random_gaussians(rng, 100, 2)
    path = tmp_path / "scan.ply"
    splat_io.save(g, path)
    other = bpy.data.objects.new("other", None)
    bpy.context.scene.collection.objects.link(other)
    other.select_set(True)
    assert bpy.ops.splat.import_splats(filepath=str(path)) == {"FINISHED"}
    obj = bpy.context.active_object
    assert obj.name == "scan" and obj.select_get() and not other.select_get()
    assert splat_object.is_splat_object(obj) and obj.splat.source_path == str(path)
    assert bs.gaussians_equal(bs.mesh_gaussians(obj), g)
    # several files at once (as a multi-file drop gives them)
    splat_io.save(g.subset(slice(0, 10)), tmp_path / "b.ply")
    bpy.ops.splat.import_splats(directory=str(tmp_path), files=[{"name": "scan.ply"},
                                                                {"name": "b.ply"}])
    assert bpy.context.active_object.name == "b" and len(bpy.context.selected_objects) == 2


def test_file_handler_and_menus_are_registered():
    handler = bpy.types.SPLAT_FH_splats
    assert handler.is_registered
    # Every readable format from the one table (a dropped .json goes through format_for).
    assert set(handler.bl_file_extensions.split(";")) == \
        {".ply", ".splat", ".spz", ".sog", ".json", ".glb", ".gltf"}
    assert handler.bl_import_operator == "splat.import_splats"
    for name in ("import_splats", "export_splats", "crop", "select_by", "clean_up", "join",
                 "apply_transform"):
        assert hasattr(bpy.types, f"SPLAT_OT_{name}"), name


def test_standard_ply_round_trip_is_bit_exact(rng, tmp_path, shared_data):
    source = tmp_path / "in.ply"
    splat_io.save(random_gaussians(rng, 300, 3), source)
    for path in (source, shared_data / "splats" / "playbot_125k_sh2.ply"):
        bs.reset_scene()
        bpy.ops.splat.import_splats(filepath=str(path))
        out = tmp_path / "out.ply"
        assert bpy.ops.splat.export_splats(filepath=str(out)) == {"FINISHED"}
        assert bs.gaussians_equal(splat_io.load(out), splat_io.load(path))
        if path == source:
            assert out.read_bytes() == source.read_bytes()


@pytest.mark.parametrize("suffix", [".spz", ".splat"])
def test_lossy_formats_round_trip_within_their_quantisation(rng, tmp_path, suffix):
    g = random_gaussians(rng, 300, 3 if suffix == ".spz" else 0)
    obj = make_object(g, antialiased=True)
    out = tmp_path / f"out{suffix}"
    # axes Y/Z: the file in Blender's own frame, so the core writer sees `g` unchanged
    assert bpy.ops.splat.export_splats(filepath=str(out), forward_axis="Y",
                                       up_axis="Z") == {"FINISHED"}
    # exactly what the core writer makes of these Gaussians (its format tests hold the bounds)
    reference = tmp_path / f"ref{suffix}"
    if suffix == ".spz":
        from addon.core.formats import spz
        spz.save(g, reference, antialiased=True)
    else:
        splat_io.save(g, reference)
    assert out.read_bytes() == reference.read_bytes()
    back = splat_io.load(out)
    assert np.abs(back.means - g.means).max() <= 2.0 ** -12  # well within either format's step
    bpy.data.objects.remove(obj)
    bpy.ops.splat.import_splats(filepath=str(out))
    assert bpy.context.active_object.splat.antialiased == (suffix == ".spz")


def test_export_to_splat_drops_sh_with_a_warning(rng, tmp_path):
    make_object(random_gaussians(rng, 20, 2))
    out = tmp_path / "x.splat"
    assert bpy.ops.splat.export_splats(filepath=str(out)) == {"FINISHED"}
    assert splat_io.load(out).degree == 0


def _write_bad(tmp_path: Path, case: str) -> Path:
    if case == "missing":
        return tmp_path / "nothing.ply"
    if case == "unknown extension":
        path = tmp_path / "scene.txt"
        path.write_text("hello")
        return path
    if case == "empty ply":
        path = tmp_path / "empty.ply"
        path.write_bytes(b"")
        return path
    if case == "garbage ply":
        path = tmp_path / "garbage.ply"
        path.write_bytes(np.random.default_rng(0).bytes(500))
        return path
    if case == "truncated ply":
        good = tmp_path / "good.ply"
        splat_io.save(random_gaussians(np.random.default_rng(0), 50, 1), good)
        path = tmp_path / "truncated.ply"
        path.write_bytes(good.read_bytes()[:-100])
        return path
    if case == "bad splat size":
        path = tmp_path / "odd.splat"
        path.write_bytes(bytes(33))
        return path
    if case == "garbage spz":
        path = tmp_path / "garbage.spz"
        path.write_bytes(b"\x1f\x8b" + bytes(40))
        return path
    raise AssertionError(case)


@pytest.mark.parametrize("case", ["missing", "unknown extension", "empty ply", "garbage ply",
                                  "truncated ply", "bad splat size", "garbage spz"])
def test_bad_files_report_an_error_and_leave_the_scene_unchanged(rng, tmp_path, case):
    make_object(random_gaussians(rng, 5, 0), "existing")
    before = bs.scene_state()
    path = _write_bad(tmp_path, case)
    with pytest.raises(RuntimeError, match="Cannot import"):
        bpy.ops.splat.import_splats(filepath=str(path))
    assert bs.scene_state() == before
    assert bpy.context.active_object.name == "existing"
    with pytest.raises(splat_io.SplatFileError):
        operators.import_splats(path)
    assert bs.scene_state() == before


def test_a_decompression_bomb_is_refused_unless_max_expansion_allows_it(rng, tmp_path, monkeypatch):
    """A 200 KB .glb showing one primitive through 400 nodes asks 332 bytes per byte: refused
    by the importer's default Max Expansion, the message saying how to raise it; with it raised,
    the read runs under that bound (and the module's is restored after)."""
    from addon.core.formats_common import limits
    from scripts import fuzz_hostile

    path = tmp_path / "instanced.glb"
    path.write_bytes(fuzz_hostile.glb_instances(nodes=400, count=3000, degree=0)["a.glb"])
    make_object(random_gaussians(rng, 5, 0), "existing")
    before = bs.scene_state()
    with pytest.raises(RuntimeError, match="Max Expansion in File > Import > Gaussian Splats"):
        bpy.ops.splat.import_splats(filepath=str(path))
    assert bs.scene_state() == before
    seen = []
    monkeypatch.setattr(operators, "read_splat_file",
                        lambda p: (seen.append(limits.MAX_EXPANSION), (random_gaussians(rng, 5, 0), False))[1])
    assert bpy.ops.splat.import_splats(filepath=str(path), max_expansion=400) == {"FINISHED"}
    assert seen == [400] and limits.MAX_EXPANSION == limits.DEFAULT_MAX_EXPANSION


def test_export_errors(rng, tmp_path):
    empty = bpy.data.objects.new("empty", None)
    bpy.context.scene.collection.objects.link(empty)
    bpy.context.view_layer.objects.active = empty
    with pytest.raises(RuntimeError):  # poll: no active splat object
        bpy.ops.splat.export_splats(filepath=str(tmp_path / "a.ply"))
    make_object(random_gaussians(rng, 5, 0))
    with pytest.raises(RuntimeError, match="does not exist"):
        bpy.ops.splat.export_splats(filepath=str(tmp_path / "no" / "such" / "a.ply"))
    with pytest.raises(RuntimeError, match="unknown splat format"):
        bpy.ops.splat.export_splats(filepath=str(tmp_path / "a.obj"))
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------- invariance

def scene_with_camera(rng, n=300, degree=3, **options):
    g = random_gaussians(rng, n, degree)
    obj = make_object(g, **options)
    camera = bs.add_camera()
    return g, obj, camera


@pytest.mark.parametrize("antialiased", [False, True])
def test_render_is_invariant_when_object_and_camera_move_together(rng, antialiased,
                                                                  record_property):
    _, obj, camera = scene_with_camera(rng, antialiased=antialiased)
    before = bs.render_scene(camera)
    assert before.alpha.max() > 0.5, "the test scene should be visible"
    rig = bpy.data.objects.new("rig", None)
    bpy.context.scene.collection.objects.link(rig)
    obj.parent = rig
    camera.parent = rig
    m = similarity_matrix(rng)
    rig.matrix_world = m
    scale = m.to_scale()[0]
    after = bs.render_scene(camera, near=0.01 * scale)
    errors = compare_renders(before, after, depth_scale=scale)
    record_property("invariance_errors", errors)
    print("blender invariance errors", errors)
    assert errors["depth_rel"] <= 1e-5
    # and the SH rotation is what makes it hold: without it the colours differ
    depsgraph = bpy.context.evaluated_depsgraph_get()
    world = gather.gather(depsgraph).gaussians
    unrotated = Gaussians(world.means, world.log_scales, world.quats, world.opacity_logits,
                          bs.mesh_gaussians(obj).sh)
    wrong = render(unrotated, bs.camera_of(camera, depsgraph), near=0.01 * scale,
                   antialiased=antialiased, threads=1)
    assert np.abs(wrong.rgb - before.rgb).max() > 1e-2


def test_export_after_transform_then_reimport_renders_the_same(rng, tmp_path):
    _, obj, camera = scene_with_camera(rng)
    obj.matrix_world = similarity_matrix(rng)
    camera.matrix_world = obj.matrix_world @ camera.matrix_world
    world = gathered().gaussians
    before = bs.render_scene(camera)
    out = tmp_path / "world.ply"
    blender_frame = {"forward_axis": "Y", "up_axis": "Z"}  # no axis conversion either way
    bpy.ops.splat.export_splats(filepath=str(out), **blender_frame)
    bpy.data.objects.remove(obj)
    bpy.ops.splat.import_splats(filepath=str(out), **blender_frame)
    reimported = bpy.context.active_object
    assert as_np(reimported.matrix_world).tolist() == np.eye(4).tolist()
    assert bs.gaussians_equal(gathered().gaussians, world)
    after = bs.render_scene(camera)
    assert np.array_equal(after.rgb, before.rgb) and np.array_equal(after.alpha, before.alpha)


def test_non_uniform_scale_is_transformed_exactly(rng):
    g, obj, _ = scene_with_camera(rng, n=50)
    obj.rotation_euler = (0.3, -0.5, 1.2)
    obj.scale = (0.5, 2.0, 1.0)
    obj.location = (1.0, 2.0, 3.0)
    result = gathered()
    matrix = as_np(obj.evaluated_get(depsgraph()).matrix_world)
    assert bs.gaussians_equal(result.gaussians, transform_gaussians(g, matrix))


def test_parenting_constraints_and_animation_apply_at_render_time(rng):
    g, obj, _ = scene_with_camera(rng, n=40)
    parent = bpy.data.objects.new("parent", None)
    target = bpy.data.objects.new("target", None)
    for other in (parent, target):
        bpy.context.scene.collection.objects.link(other)
    obj.parent = parent
    parent.rotation_euler = (0.0, 0.0, 0.7)
    target.rotation_euler = (0.4, 0.2, -0.3)
    constraint = obj.constraints.new("COPY_ROTATION")
    constraint.target = target
    constraint.mix_mode = "ADD"
    obj.location = (0.0, 0.0, 0.0)
    obj.keyframe_insert("location", frame=1)
    obj.location = (4.0, 0.0, -2.0)
    obj.keyframe_insert("location", frame=11)
    scene = bpy.context.scene
    for frame in (1, 6):
        scene.frame_set(frame)
        evaluated = obj.evaluated_get(depsgraph())
        matrix = as_np(evaluated.matrix_world)
        result = gathered()
        assert np.array_equal(result.batches[0].matrix_world, matrix)
        assert bs.gaussians_equal(result.gaussians, transform_gaussians(g, matrix))
    assert np.allclose(matrix[:3, 3], (2.0 * np.cos(0.7), 2.0 * np.sin(0.7), -1.0), atol=1e-5)


def test_object_options_apply(rng):
    g, obj, _ = scene_with_camera(rng, n=30)
    obj.splat.sh_degree = 1
    result = gathered()
    assert result.gaussians.degree == 1
    assert np.array_equal(result.gaussians.sh, g.sh[:, :4])
    obj.splat.antialiased = True
    assert gathered().antialiased
    second = make_object(random_gaussians(rng, 10, 0), "second")
    result = gathered()
    assert len(result.gaussians) == 40 and result.gaussians.degree == 1
    assert not result.antialiased and result.warnings  # they disagree
    second.hide_viewport = True
    assert len(gathered().gaussians) == 30


def test_save_and_reopen_in_a_fresh_process_renders_the_same(rng, tmp_path):
    _, obj, camera = scene_with_camera(rng)
    obj.matrix_world = similarity_matrix(rng)
    camera.matrix_world = obj.matrix_world @ camera.matrix_world
    obj.splat.antialiased = True
    obj.splat.sh_degree = 2
    before = bs.render_scene(camera)
    blend = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    out = tmp_path / "after.npz"
    script = textwrap.dedent(f"""
        import sys, json
        sys.path.insert(0, {str(ROOT)!r}); sys.path.insert(0, {str(ROOT / 'tests')!r})
        import numpy as np
        import bpy_support as bs
        from bpy_support import bpy
        bs.ensure_registered()
        bpy.ops.wm.open_mainfile(filepath={str(blend)!r})
        obj = bpy.data.objects[{obj.name!r}]
        result = bs.render_scene(bpy.data.objects[{camera.name!r}])
        np.savez({str(out)!r}, rgb=result.rgb, alpha=result.alpha, depth=result.depth)
        print(json.dumps(dict(is_splat=obj.splat.is_splat, antialiased=obj.splat.antialiased,
                              sh_degree=obj.splat.sh_degree)))
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=120, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-3000:]
    options = json.loads(done.stdout.strip().splitlines()[-1])
    assert options == {"is_splat": True, "antialiased": True, "sh_degree": 2}
    after = np.load(out)
    assert np.array_equal(after["rgb"], before.rgb) and np.array_equal(after["alpha"], before.alpha)
    assert np.array_equal(after["depth"], before.depth)


# ------------------------------------------------------------------------------- editing

def select_vertices(obj, mask: np.ndarray) -> None:
    obj.data.vertices.foreach_set("select", mask)
    obj.data.update()


def test_edit_mode_delete_and_hide_remove_splats_from_renders(rng):
    g, obj, _ = scene_with_camera(rng, n=60)
    delete = np.zeros(60, bool)
    delete[[3, 10, 11, 40]] = True
    select_vertices(obj, delete)
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.delete(type="VERT")
    kept = g.subset(~delete)
    assert bs.gaussians_equal(gathered().gaussians, kept)  # still in Edit Mode
    bpy.ops.mesh.select_all(action="DESELECT")
    bpy.ops.object.mode_set(mode="OBJECT")
    hide = np.zeros(56, bool)
    hide[[0, 5, 6]] = True
    select_vertices(obj, hide)
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.hide(unselected=False)
    assert bs.gaussians_equal(gathered().gaussians, kept.subset(~hide))  # hidden in Edit Mode
    bpy.ops.object.mode_set(mode="OBJECT")
    assert bs.gaussians_equal(gathered().gaussians, kept.subset(~hide))  # and after it
    assert bs.gaussians_equal(bs.mesh_gaussians(obj), kept)  # still in the data
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.reveal()
    bpy.ops.object.mode_set(mode="OBJECT")
    assert bs.gaussians_equal(gathered().gaussians, kept)


def test_edit_mode_gathers_the_same_gaussians_until_an_edit(rng):
    """In Edit Mode nothing is cached by data address, yet an unchanged edit mesh must give the
    same Gaussians object: the viewport keys its image on it, and would otherwise render the
    same view again at every redraw, for as long as Edit Mode lasts."""
    g, obj, _ = scene_with_camera(rng, n=60)
    bpy.context.view_layer.objects.active = obj
    bpy.ops.object.mode_set(mode="EDIT")
    try:
        first, second = gathered().gaussians, gathered().gaussians
        assert second is first and bs.gaussians_equal(first, g)
        bpy.ops.mesh.select_all(action="DESELECT")
        bpy.ops.object.mode_set(mode="OBJECT")
        select_vertices(obj, np.arange(60) < 5)
        bpy.ops.object.mode_set(mode="EDIT")
        bpy.ops.mesh.delete(type="VERT")
        edited = gathered().gaussians
        assert edited is not first and len(edited) == 55
        assert gathered().gaussians is edited
    finally:
        bpy.ops.object.mode_set(mode="OBJECT")


def test_separate_and_join_keep_every_attribute(rng):
    g, obj, _ = scene_with_camera(rng, n=50)
    obj.data.attributes.new("my_weight", "FLOAT", "POINT").data.foreach_set(
        "value", np.arange(50, dtype=np.float32))
    part = np.zeros(50, bool)
    part[::3] = True
    select_vertices(obj, part)
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.separate(type="SELECTED")
    bpy.ops.object.mode_set(mode="OBJECT")
    piece = next(o for o in bpy.data.objects if o.type == "MESH" and o is not obj)
    assert splat_object.is_splat_object(piece)
    assert bs.gaussians_equal(bs.mesh_gaussians(piece), g.subset(part))
    assert bs.gaussians_equal(bs.mesh_gaussians(obj), g.subset(~part))
    weights = np.empty(len(piece.data.vertices), np.float32)
    piece.data.attributes["my_weight"].data.foreach_get("value", weights)
    assert np.array_equal(weights, np.flatnonzero(part).astype(np.float32))
    # Blender's own Join, objects sharing a transform: everything concatenated as is
    bpy.ops.object.select_all(action="DESELECT")
    obj.select_set(True)
    piece.select_set(True)
    bpy.context.view_layer.objects.active = obj
    bpy.ops.object.join()
    joined = bs.mesh_gaussians(obj)
    assert bs.gaussians_equal(joined, Gaussians(*(
        np.concatenate([a, b]) for a, b in zip(g.subset(~part).arrays().values(),
                                               g.subset(part).arrays().values()))))


def test_splat_join_transforms_every_parameter(rng):
    a = random_gaussians(rng, 30, 3)
    b = random_gaussians(rng, 20, 1)
    obj_a = make_object(a, "a")
    obj_b = make_object(b, "b")
    obj_a.matrix_world = similarity_matrix(rng)
    obj_b.matrix_world = similarity_matrix(rng)
    obj_b.scale = (1.0, 2.0, 0.5)  # non-uniform: shapes stay exact
    before = gathered().gaussians
    bpy.ops.object.select_all(action="DESELECT")
    obj_a.select_set(True)
    obj_b.select_set(True)
    bpy.context.view_layer.objects.active = obj_a
    assert bpy.ops.splat.join() == {"FINISHED"}
    assert [o.name for o in bpy.data.objects if o.type == "MESH"] == ["a"]
    after = gathered().gaussians
    assert len(after) == 50 and after.degree == 3
    order = np.lexsort(before.means.T), np.lexsort(after.means.T)
    x, y = before.subset(order[0]), after.subset(order[1])
    assert np.allclose(x.means, y.means, atol=1e-4)
    cx, cy = covariances(x), covariances(y)
    assert np.all(np.abs(cx - cy).max(axis=(1, 2)) <= 1e-4 * np.abs(cx).max(axis=(1, 2)))
    assert np.abs(x.sh[:, :4] - y.sh[:, :4]).max() <= 1e-4  # b's bands are rotated to match


def test_apply_transform_bakes_splats_and_keeps_the_render(rng):
    g, obj, camera = scene_with_camera(rng, n=200)
    obj.matrix_world = similarity_matrix(rng)
    camera.matrix_world = obj.matrix_world @ camera.matrix_world
    before = bs.render_scene(camera)
    world = gathered().gaussians
    assert bpy.ops.splat.apply_transform() == {"FINISHED"}
    assert np.allclose(as_np(obj.matrix_world), np.eye(4))
    assert bs.gaussians_equal(bs.mesh_gaussians(obj), world)
    after = bs.render_scene(camera)
    assert np.array_equal(after.rgb, before.rgb)


# ---------------------------------------------------------------------- geometry nodes

def node_modifier(obj, name="nodes"):
    tree = bpy.data.node_groups.new(name, "GeometryNodeTree")
    tree.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    modifier = obj.modifiers.new(name, "NODES")
    modifier.node_group = tree
    nodes = tree.nodes
    return tree, nodes.new("NodeGroupInput"), nodes.new("NodeGroupOutput")


def test_geometry_nodes_delete_is_reflected_in_gather(rng):
    g, obj, _ = scene_with_camera(rng, n=80)
    tree, group_in, group_out = node_modifier(obj)
    attribute = tree.nodes.new("GeometryNodeInputNamedAttribute")
    attribute.data_type = "FLOAT"
    attribute.inputs["Name"].default_value = "opacity_logit"
    compare = tree.nodes.new("FunctionNodeCompare")
    compare.data_type, compare.operation = "FLOAT", "LESS_THAN"
    compare.inputs[1].default_value = 0.0
    delete = tree.nodes.new("GeometryNodeDeleteGeometry")
    tree.links.new(attribute.outputs["Attribute"], compare.inputs[0])
    tree.links.new(compare.outputs["Result"], delete.inputs["Selection"])
    tree.links.new(group_in.outputs[0], delete.inputs["Geometry"])
    tree.links.new(delete.outputs[0], group_out.inputs[0])
    result = gathered()
    assert bs.gaussians_equal(result.gaussians, g.subset(g.opacity_logits >= 0))
    assert len(obj.data.vertices) == 80  # the original is untouched
    compare.inputs[1].default_value = 1.0  # editing the node tree invalidates the cache
    assert bs.gaussians_equal(gathered().gaussians, g.subset(g.opacity_logits >= 1))


def test_geometry_nodes_instances_and_point_clouds(rng):
    g, obj, _ = scene_with_camera(rng, n=25)
    obj.location = (0.5, 0.0, 0.0)
    tree, group_in, group_out = node_modifier(obj)
    to_instance = tree.nodes.new("GeometryNodeGeometryToInstance")
    transform = tree.nodes.new("GeometryNodeTransform")
    transform.inputs["Translation"].default_value = (0.0, 1.0, 2.0)
    transform.inputs["Rotation"].default_value = (0.4, -0.2, 1.0)
    transform.inputs["Scale"].default_value = (2.0, 2.0, 2.0)
    tree.links.new(group_in.outputs[0], to_instance.inputs[0])
    tree.links.new(to_instance.outputs[0], transform.inputs[0])
    tree.links.new(transform.outputs[0], group_out.inputs[0])
    result = gathered()
    assert len(result.batches) == 1 and result.batches[0].is_instance
    euler = mathutils.Euler((0.4, -0.2, 1.0))
    local = (mathutils.Matrix.Translation((0.0, 1.0, 2.0)) @ euler.to_matrix().to_4x4()
             @ mathutils.Matrix.Scale(2.0, 4))
    want = as_np(obj.matrix_world) @ as_np(local)
    assert np.allclose(result.batches[0].matrix_world, want, atol=1e-6)
    assert bs.gaussians_equal(result.gaussians,
                              transform_gaussians(g, result.batches[0].matrix_world))
    # Mesh to Points: the splats arrive as a point cloud
    for node in list(tree.nodes):
        if node not in (group_in, group_out):
            tree.nodes.remove(node)
    to_points = tree.nodes.new("GeometryNodeMeshToPoints")
    tree.links.new(group_in.outputs[0], to_points.inputs["Mesh"])
    tree.links.new(to_points.outputs[0], group_out.inputs[0])
    result = gathered()
    assert len(result.batches) == 1
    assert bs.gaussians_equal(result.gaussians, transform_gaussians(g, as_np(obj.matrix_world)))


def test_instance_on_points_of_another_object(rng):
    g, source, _ = scene_with_camera(rng, n=15)
    source.hide_viewport = True  # hidden source, as usual for instancing
    points = bpy.data.meshes.new("points")
    points.from_pydata([(0, 0, 0), (3, 0, 0), (0, 3, 1)], [], [])
    instancer = bpy.data.objects.new("instancer", points)
    bpy.context.scene.collection.objects.link(instancer)
    instancer.rotation_euler = (0.0, 0.0, 0.5)
    tree, group_in, group_out = node_modifier(instancer)
    info = tree.nodes.new("GeometryNodeObjectInfo")
    info.inputs["Object"].default_value = source
    info.inputs["As Instance"].default_value = True
    on_points = tree.nodes.new("GeometryNodeInstanceOnPoints")
    tree.links.new(group_in.outputs[0], on_points.inputs["Points"])
    tree.links.new(info.outputs["Geometry"], on_points.inputs["Instance"])
    tree.links.new(on_points.outputs[0], group_out.inputs[0])
    result = gathered()
    assert len(result.batches) == 3 and len(result.gaussians) == 45
    base = as_np(instancer.matrix_world)
    found = sorted(tuple(np.round(b.matrix_world[:3, 3], 5)) for b in result.batches)
    want = sorted(tuple(np.round(base[:3, :3] @ p + base[:3, 3], 5))
                  for p in np.array([(0, 0, 0), (3, 0, 0), (0, 3, 1)], float))
    assert found == want
    for batch in result.batches:
        assert bs.gaussians_equal(batch.gaussians, transform_gaussians(g, batch.matrix_world))


# ------------------------------------------------------------------------------- cache

def test_gather_cache_hits_and_invalidation(rng):
    g, obj, _ = scene_with_camera(rng, n=40)
    first = gathered()
    assert first.cache_hits == 0
    second = gathered()
    assert second.cache_hits == 1 and second.gaussians is first.gaussians
    obj.location = (1.0, 0.0, 0.0)  # moved: transformed again
    moved = gathered()
    assert moved.cache_hits == 0 and np.allclose(moved.gaussians.means, g.means + (1, 0, 0))
    new_logits = np.full(40, 2.0, np.float32)  # data edited: read again
    obj.data.attributes["opacity_logit"].data.foreach_set("value", new_logits)
    obj.data.update()
    edited = gathered()
    assert edited.cache_hits == 0 and np.array_equal(edited.gaussians.opacity_logits, new_logits)
    obj.splat.sh_degree = 0  # options are part of the key
    assert gathered().gaussians.degree == 0
    assert gathered().cache_hits == 1
    obj.data.vertices[0].co = (9.0, 9.0, 9.0)  # a single-vertex edit through RNA
    assert gathered().gaussians.means[0].tolist() == [10.0, 9.0, 9.0]
