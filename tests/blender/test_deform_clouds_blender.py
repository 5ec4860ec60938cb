"""Blender 5.3's splat point clouds that a stack deforms (addon/blender/sources/blender_cloud.py
through sources/deformed.py): shapes and SH follow the deformation, as for the add-on's objects.

This bpy (5.0.1) has no 'GAUSSIAN_SPLAT' point clouds: a point cloud holding Blender's splat
attributes stands in for one (`radiance:base` as FLOAT_COLOR, as
tests/blender/blender_splats/test_blender_splats_bpy.py has it). A point cloud takes geometry
nodes, so the stack here is a Set Position node that takes each point to where a Simple Deform
puts the same vertex of a helper mesh (`follow_mesh`). The checks in the official bpy 5.3.0
are tests/real_blender/splats53.py's (`deform`).

- The issue's bent row as a cloud: no empty pixel rows along the arc (some with the centres
  alone).
- The cloud bent by the stack equals the add-on's object bent by the same Simple Deform (one
  code path: the same Gaussians to the float32 rounding of Blender's attribute convention).
- Nothing runs for a cloud without a stack; nothing is recomputed while the deformation stays;
  a stack that changes the point count moves the centres only; hidden points stay hidden.
"""

from __future__ import annotations

import bpy_support as bs
from bpy_support import bpy
import numpy as np
import pytest

from addon.blender import splat_object
from addon.blender.blender_splats import data
from addon.blender.sources import blender_cloud, deformed, gather
from addon.core.blender_splats import attributes
from addon.core.gaussians import Gaussians
from addon.core.transform import covariances
from scenes import random_gaussians
from test_deform_blender import empty_rows_along_the_arc, row_of_dashes


@pytest.fixture(autouse=True)
def stand_in(monkeypatch):
    """Before 5.3: a point cloud with `radiance:base` counts as Blender splats."""
    bs.reset_scene()
    if not data.supported():
        monkeypatch.setattr(data, "is_blender_splat_data", lambda d: isinstance(
            d, bpy.types.PointCloud) and "radiance:base" in d.attributes)
    yield
    gather.clear_cache()


def splat_cloud(gaussians: Gaussians, name: str = "Cloud"):
    """A point cloud object holding Blender's splat attributes for `gaussians`."""
    if data.supported():
        return data.create_object(gaussians, name)
    pointcloud = data._sized_pointcloud(name, len(gaussians))
    for attr_name, values in attributes.attributes_from_gaussians(gaussians).items():
        data_type = attributes.REQUIRED.get(attr_name, attributes.SH_TYPE)[0]
        data_type = "FLOAT_COLOR" if data_type == "FLOAT4" else data_type
        attribute = pointcloud.attributes.get(attr_name) or pointcloud.attributes.new(
            attr_name, data_type, "POINT")
        attribute.data.foreach_set(data._KEYS[data_type][0], np.ascontiguousarray(values).ravel())
    obj = bpy.data.objects.new(name, pointcloud)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def bent_helper(means: np.ndarray, angle: float = np.pi):
    """A mesh of bare vertices at `means`, bent by a Simple Deform about Z."""
    mesh = bpy.data.meshes.new("Helper")
    mesh.vertices.add(len(means))
    mesh.vertices.foreach_set("co", np.asarray(means, np.float32).ravel())
    helper = bpy.data.objects.new("Helper", mesh)
    bpy.context.scene.collection.objects.link(helper)
    bend = helper.modifiers.new("Bend", "SIMPLE_DEFORM")
    bend.deform_method, bend.deform_axis, bend.angle = "BEND", "Z", angle
    return helper


def follow_mesh(obj, helper, *, delete_first: bool = False):
    """Geometry nodes on `obj`: each point to where `helper`'s evaluated vertex of the same index
    is (object space); `delete_first` deletes point 0 first (the count changes)."""
    group = bpy.data.node_groups.new("Follow", "GeometryNodeTree")
    group.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    group.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    nodes, links = group.nodes, group.links
    source, out = nodes.new("NodeGroupInput"), nodes.new("NodeGroupOutput")
    info = nodes.new("GeometryNodeObjectInfo")
    info.transform_space = "ORIGINAL"
    info.inputs["Object"].default_value = helper
    sample = nodes.new("GeometryNodeSampleIndex")
    sample.data_type, sample.domain = "FLOAT_VECTOR", "POINT"
    links.new(info.outputs["Geometry"], sample.inputs["Geometry"])
    links.new(nodes.new("GeometryNodeInputPosition").outputs[0], sample.inputs["Value"])
    links.new(nodes.new("GeometryNodeInputIndex").outputs[0], sample.inputs["Index"])
    move = nodes.new("GeometryNodeSetPosition")
    links.new(sample.outputs[0], move.inputs["Position"])
    geometry = source.outputs[0]
    if delete_first:
        delete = nodes.new("GeometryNodeDeleteGeometry")
        compare = nodes.new("FunctionNodeCompare")
        compare.data_type, compare.operation = "INT", "EQUAL"
        links.new(nodes.new("GeometryNodeInputIndex").outputs[0], compare.inputs[2])
        compare.inputs[3].default_value = 0
        links.new(geometry, delete.inputs["Geometry"])
        links.new(compare.outputs[0], delete.inputs["Selection"])
        geometry = delete.outputs[0]
    links.new(geometry, move.inputs["Geometry"])
    links.new(move.outputs[0], out.inputs[0])
    modifier = obj.modifiers.new("Follow", "NODES")
    modifier.node_group = group
    return modifier


def ortho_from_above():
    camera = bs.add_camera(location=(0.0, 0.3, 5.0), rotation=(0.0, 0.0, 0.0), width=160,
                           height=160)
    camera.data.type, camera.data.ortho_scale = "ORTHO", 2.0
    return camera


def test_a_bent_row_cloud_renders_as_one_continuous_arc(monkeypatch):
    row = row_of_dashes()
    cloud = splat_cloud(row, "Row")
    follow_mesh(cloud, bent_helper(row.means))
    camera = ortho_from_above()
    bent = empty_rows_along_the_arc(camera)
    with monkeypatch.context() as patch:  # before: the centres alone followed the bend
        patch.setattr(blender_cloud.BlenderCloud, "rest_data", lambda self: None)
        centres_only = empty_rows_along_the_arc(camera)
    print(f"cloud, empty rows along the arc: {centres_only:.1%} with the centres alone, "
          f"{bent:.1%} bent")
    assert centres_only > 0.05
    assert bent == 0.0


def _world(name: str) -> Gaussians:
    result = gather.gather(bpy.context.evaluated_depsgraph_get(), use_cache=False)
    (batch,) = [b for b in result.batches if b.name == name]
    return batch.gaussians


def test_a_cloud_bends_as_the_addons_object_bent_by_the_same_stack(rng, monkeypatch):
    g = random_gaussians(rng, 600, 3, radius=0.5, stray=0.0)
    ours = splat_object.create_splat_object(g, "Ours")
    bend = ours.modifiers.new("Bend", "SIMPLE_DEFORM")
    bend.deform_method, bend.deform_axis, bend.angle = "BEND", "Z", 2.0
    cloud = splat_cloud(g, "Cloud")
    follow_mesh(cloud, bent_helper(g.means, 2.0))
    for obj in (ours, cloud):  # the same place, turned and scaled: the matrix folded in
        obj.location, obj.rotation_euler, obj.scale = (0.3, -0.2, 0.1), (0.4, 0.1, -0.7), (1.3, 0.8, 1.1)
    a, b = _world("Ours"), _world("Cloud")
    assert np.abs(a.means - g.means).max() > 0.1  # bent, not as stored
    np.testing.assert_array_equal(a.means, b.means)
    ca, cb = covariances(a), covariances(b)
    relative = np.abs(ca - cb).max(axis=(1, 2)) / np.abs(ca).max(axis=(1, 2))
    sig = lambda x: 1 / (1 + np.exp(-x.astype(np.float64)))  # noqa: E731
    print(f"cloud against the add-on's object: covariance {relative.max():.2g} (relative), "
          f"SH {np.abs(a.sh - b.sh).max():.2g}")
    assert relative.max() <= 1e-5  # scales stored linear in the cloud: exp then log
    assert np.abs(sig(a.opacity_logits) - sig(b.opacity_logits)).max() <= 1.2e-7
    np.testing.assert_allclose(b.sh, a.sh, rtol=0, atol=2e-6)
    monkeypatch.setattr(blender_cloud.BlenderCloud, "rest_data", lambda self: None)
    unbent = covariances(_world("Cloud"))  # the centres alone: far from it
    assert (np.abs(unbent - cb).max(axis=(1, 2)) / np.abs(cb).max(axis=(1, 2))).max() > 0.1


def test_a_cloud_without_a_stack_reads_as_before(rng, monkeypatch):
    g = random_gaussians(rng, 200, 2)
    cloud = splat_cloud(g, "Cloud")
    monkeypatch.setattr(deformed, "deform", lambda *a, **k: pytest.fail("deformed without a stack"))
    want = data.read_gaussians(cloud.data)
    assert bs.gaussians_equal(_world("Cloud"), want)
    follow_mesh(cloud, bent_helper(g.means, 0.0))  # a stack that moves nothing
    assert bs.gaussians_equal(_world("Cloud"), want)


def test_nothing_is_recomputed_while_the_deformation_stays(rng, monkeypatch):
    g = random_gaussians(rng, 300, 1, radius=0.5, stray=0.0)
    cloud = splat_cloud(g, "Cloud")
    helper = bent_helper(g.means, 1.0)
    follow_mesh(cloud, helper)
    calls = []
    real = deformed.deform
    monkeypatch.setattr(deformed, "deform", lambda *a, **k: calls.append(1) or real(*a, **k))
    first = gather.gather(bpy.context.evaluated_depsgraph_get())
    again = gather.gather(bpy.context.evaluated_depsgraph_get())
    assert calls == [1] and again.cache_hits == 1 and again.gaussians is first.gaussians
    helper.modifiers["Bend"].angle = 1.5
    bpy.context.view_layer.update()
    bent_more = gather.gather(bpy.context.evaluated_depsgraph_get())
    assert calls == [1, 1] and bent_more.cache_hits == 0
    assert not np.array_equal(bent_more.gaussians.means, first.gaussians.means)


def test_a_stack_that_changes_the_count_moves_the_centres_only(rng, monkeypatch):
    g = random_gaussians(rng, 100, 1, radius=0.5, stray=0.0)
    cloud = splat_cloud(g, "Cloud")
    follow_mesh(cloud, bent_helper(g.means, 1.0), delete_first=True)
    monkeypatch.setattr(deformed, "deform", lambda *a, **k: pytest.fail("deformed another count"))
    got = _world("Cloud")
    assert len(got) == 99
    np.testing.assert_array_equal(got.quats, g.quats[1:])


def test_hidden_points_of_a_bent_cloud_stay_hidden(rng):
    g = random_gaussians(rng, 120, 1, radius=0.5, stray=0.0)
    cloud = splat_cloud(g, "Cloud")
    helper = bent_helper(g.means, 1.0)
    follow_mesh(cloud, helper)
    full = _world("Cloud")
    hide = np.zeros(len(g), bool)
    hide[::7] = True
    attribute = cloud.data.attributes.new(data.HIDE, "BOOLEAN", "POINT")
    attribute.data.foreach_set("value", hide)
    cloud.data.update_tag()
    bpy.context.view_layer.update()
    shown = _world("Cloud")
    assert len(shown) == int((~hide).sum())
    assert bs.gaussians_equal(shown, full.subset(~hide))  # each shape bent with all neighbours


def test_a_point_left_out_for_nan_leaves_the_others_bent_as_without_it(rng):
    """A point holding NaN is dropped when read; the others bend with the rest positions of
    the points kept, as a cloud that never had it."""
    g = random_gaussians(rng, 150, 1, radius=0.5, stray=0.0)
    broken = splat_cloud(g, "Broken")
    rotation = broken.data.attributes[attributes.ROTATION]
    quats = g.quats.copy()
    quats[5] = np.nan
    rotation.data.foreach_set("value", quats.ravel())
    follow_mesh(broken, bent_helper(g.means, 1.0))
    keep = np.arange(len(g)) != 5
    whole = splat_cloud(g.subset(keep), "Whole")
    follow_mesh(whole, bent_helper(g.means[keep], 1.0))
    for obj in (broken, whole):
        obj.location = (0.2, 0.1, -0.3)
    got, want = _world("Broken"), _world("Whole")
    assert len(got) == len(g) - 1
    assert bs.gaussians_equal(got, want)
