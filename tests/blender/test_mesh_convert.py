"""Splats to a textured mesh in Blender (bpy): `bpy.ops.splat.convert_to_mesh` and
`mesh_convert.convert_to_mesh` on a small sphere of Gaussians at low resolution."""

from __future__ import annotations

import bpy_support as bs
from bpy_support import bpy  # the shared bpy import
import numpy as np
import pytest

from types import SimpleNamespace

from addon.blender import job_runner, mesh_convert, splat_object
from addon.blender.sources import gather
from addon.core.mesh import surface
from addon.core.mesh.surface import Cancelled
from scenes import sphere_gaussians


@pytest.fixture(autouse=True)
def empty_scene():
    bs.reset_scene()
    yield
    gather.clear_cache()


def _splat_sphere():
    obj = splat_object.create_splat_object(sphere_gaussians(1.0, 1500, 0.07), "Ball")
    obj.location = (2.0, 0.0, 1.0)
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    return obj


SMALL = dict(resolution=24, max_triangles=600, texture_size=64, view_count=16, view_size=48)


def test_operator_converts_the_active_splat_object(capsys):
    obj = _splat_sphere()
    result = bpy.ops.splat.convert_to_mesh(**SMALL)
    assert result == {"FINISHED"}
    # Headless, the terminal gets a line per stage (job_runner), then the report.
    lines = capsys.readouterr().out.splitlines()
    stages = [line.split(":")[1].split("(")[0].strip() for line in lines
              if line.startswith("Converting to mesh: ")]
    assert stages == list(mesh_convert.STAGES) + ["done"]
    assert "triangles" in lines[-1]
    mesh_obj = bpy.context.view_layer.objects.active
    assert mesh_obj is not obj and mesh_obj.type == "MESH"
    assert mesh_obj[mesh_convert.SOURCE_KEY] == obj
    mesh = mesh_obj.data
    assert 0 < len(mesh.polygons) <= SMALL["max_triangles"]
    assert all(len(p.vertices) == 3 for p in mesh.polygons)
    assert "UVMap" in mesh.uv_layers
    uv = np.empty(len(mesh.loops) * 2, np.float32)
    mesh.uv_layers["UVMap"].data.foreach_get("uv", uv)
    assert uv.min() >= 0 and uv.max() <= 1
    material = mesh.materials[0]
    images = [n.image for n in material.node_tree.nodes if n.type == "TEX_IMAGE"]
    assert images and images[0].size[:] == (64, 64) and images[0].packed_file is not None
    assert images[0].colorspace_settings.name == "sRGB"
    # World space, around the moved object; the top is red and the bottom blue.
    co = np.empty(len(mesh.vertices) * 3, np.float32)
    mesh.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3)
    assert np.allclose(co.mean(axis=0), (2, 0, 1), atol=0.1)
    r = np.linalg.norm(co - (2, 0, 1), axis=1)
    assert np.abs(r - 1.0).max() < 0.35
    px = np.array(images[0].pixels[:]).reshape(64, 64, 4)
    loop_v = np.empty(len(mesh.loops), np.int32)
    mesh.loops.foreach_get("vertex_index", loop_v)
    uvr = uv.reshape(-1, 2)
    top = co[loop_v, 2] > 1.5
    bottom = co[loop_v, 2] < 0.5
    def sample(m):
        return px[(uvr[m, 1] * 63).round().astype(int), (uvr[m, 0] * 63).round().astype(int), :3]
    assert sample(top)[:, 0].mean() > 0.6 and sample(top)[:, 2].mean() < 0.3
    assert sample(bottom)[:, 2].mean() > 0.6 and sample(bottom)[:, 0].mean() < 0.3


def test_proxy_flags_and_watertight_budget():
    obj = _splat_sphere()
    stats = {}
    new = mesh_convert.convert_to_mesh(obj, proxy=True, stats=stats, cameras="SPHERE", **SMALL)
    assert new.is_shadow_catcher and new.visible_shadow and not new.visible_glossy
    assert any(m.type == "COLLISION" for m in new.modifiers)
    assert new[mesh_convert.PROXY_KEY] == obj
    assert stats["triangles"] <= SMALL["max_triangles"] < stats["extracted_triangles"]
    faces = np.array([p.vertices[:] for p in new.data.polygons])
    assert surface.is_watertight(faces)


def test_bad_input_reports_and_leaves_nothing():
    cube = bpy.data.objects.new("Cube", bpy.data.meshes.new("Cube"))
    bpy.context.scene.collection.objects.link(cube)
    bpy.context.view_layer.objects.active = cube
    before = bs.scene_state()
    with pytest.raises(RuntimeError, match="not a splat object"):
        bpy.ops.splat.convert_to_mesh(**SMALL)
    assert bs.scene_state() == before
    obj = _splat_sphere()
    with pytest.raises(mesh_convert.ConversionError, match="COLMAP"):
        mesh_convert.convert_to_mesh(obj, cameras="COLMAP", **SMALL)


def test_cancel_leaves_nothing_behind():
    obj = _splat_sphere()
    before = bs.scene_state()
    images, materials = len(bpy.data.images), len(bpy.data.materials)
    calls = []

    def cancel():
        calls.append(1)
        return len(calls) > 5

    with pytest.raises(Cancelled):
        mesh_convert.convert_to_mesh(obj, cancel=cancel, **SMALL)
    assert bs.scene_state() == before
    assert (len(bpy.data.images), len(bpy.data.materials)) == (images, materials)


class _Harness(job_runner.JobOperator):
    """The runner's modal half without an Operator (no window: events are made by hand)."""

    def __init__(self, key: str) -> None:
        self._key = key
        self.reports: list = []

    def report(self, level, message) -> None:
        self.reports.append((level, message))


def test_modal_conversion_steps_on_timer_ticks_and_esc_leaves_nothing(monkeypatch):
    monkeypatch.setattr(job_runner, "STAGE_BUDGET", 0.0)  # one step per tick
    obj = _splat_sphere()
    before = bs.scene_state()
    tick = SimpleNamespace(type="TIMER", value="NOTHING")

    def start():
        stats: dict = {}
        steps = mesh_convert.convert_job(obj, stats=stats, **SMALL)
        job = job_runner.OperatorJob(
            "mesh:test", "Converting to mesh", mesh_convert.StagedJob(steps, mesh_convert.STAGES),
            lambda running, write: ("INFO", "done", running.job.result))
        job_runner.RUNNING[job.key] = job
        job.job.start()
        return job, _Harness(job.key)

    job, harness = start()
    for _ in range(2):  # a step of work each: "render" 0, then the first view
        assert harness.modal(bpy.context, tick) == {"PASS_THROUGH"}
    assert 0 < job.progress.fraction < 1 and job.progress.message in mesh_convert.STAGES
    assert harness.modal(bpy.context, SimpleNamespace(type="ESC", value="PRESS")) == \
        {"RUNNING_MODAL"}
    assert harness.modal(bpy.context, tick) == {"FINISHED"}
    assert job.job.progress().phase == "cancelled" and job.key not in job_runner.RUNNING
    assert bs.scene_state() == before

    job, harness = start()
    result = None
    for _ in range(10_000):
        result = harness.modal(bpy.context, tick)
        if result != {"PASS_THROUGH"}:
            break
    assert result == {"FINISHED"} and job.job.result.type == "MESH"
    assert bpy.context.view_layer.objects.active == job.job.result
