"""Blender 5.3's own splat point clouds in the add-on, at the bpy level, in our venv's bpy.

Our venv's bpy (5.0.1) has point clouds but no 'GAUSSIAN_SPLAT' type and no FLOAT4 attributes.
What it can show is tested here: the feature says it is absent (operators grey out, functions
raise a clear error, nothing crashes), and every reading path (gather for F12 and the viewport,
export, crop, select, clean up, remove points) on a point cloud holding Blender's splat
attributes, with the type test stood in for (`radiance:base` as FLOAT_COLOR, which reads the
same way). Writing Blender's splats and the checks against Blender's own importers need 5.3:
`tests/real_blender/splats53.py` runs them in the official bpy 5.3.0.
"""

from __future__ import annotations

import bpy_support as bs
from bpy_support import bpy
import numpy as np
import pytest

from addon.blender import splat_object
from addon.blender.sources import gather
from addon.blender.blender_splats import any_splats, convert, data, ownership
from addon.blender.io import operators
from addon.blender.render import compositor_bridge as bridge
from addon.core import splat_io
from addon.core.blender_splats import attributes
from addon.core.transform import transform_gaussians
from scenes import random_gaussians

HAS_53 = data.supported()


@pytest.fixture(autouse=True)
def empty_scene():
    bs.reset_scene()
    yield
    gather.clear_cache()


def _stand_in_cloud(gaussians, name="Cloud"):
    """A point cloud holding Blender's splat attributes for `gaussians` (radiance:base as
    FLOAT_COLOR where this Blender lacks FLOAT4)."""
    arrays = attributes.attributes_from_gaussians(gaussians)
    pointcloud = data._sized_pointcloud(name, len(gaussians))
    for attr_name, values in arrays.items():
        data_type = attributes.REQUIRED.get(attr_name, attributes.SH_TYPE)[0]
        if data_type == "FLOAT4" and not HAS_53:
            data_type = "FLOAT_COLOR"
        attribute = pointcloud.attributes.get(attr_name) or pointcloud.attributes.new(attr_name, data_type, "POINT")
        attribute.data.foreach_set(data._KEYS[data_type][0], np.ascontiguousarray(values).reshape(-1))
    if HAS_53:
        pointcloud.type = data.GAUSSIAN_SPLAT
    obj = bpy.data.objects.new(name, pointcloud)
    bpy.context.scene.collection.objects.link(obj)
    return obj


@pytest.fixture
def stand_in(monkeypatch):
    """Before 5.3: a point cloud with `radiance:base` counts as Blender splats."""
    if not HAS_53:
        monkeypatch.setattr(data, "is_blender_splat_data", lambda d: isinstance(
            d, bpy.types.PointCloud) and "radiance:base" in d.attributes)


@pytest.mark.skipif(HAS_53, reason="this bpy has Gaussian splat point clouds")
def test_before_53_the_feature_is_absent_and_clear(rng):
    assert not data.supported()
    g = random_gaussians(rng, 20, degree=1)
    with pytest.raises(data.BlenderSplatsUnsupported, match="5.3"):
        data.new_pointcloud(g, "x")
    obj = splat_object.create_splat_object(g, "Ours")
    before = bs.scene_state()
    with pytest.raises(data.BlenderSplatsUnsupported):
        convert.to_blender_splats(obj)
    assert bs.scene_state() == before
    with bpy.context.temp_override(selected_objects=[obj], active_object=obj):
        assert not bpy.ops.splat.convert_to_blender_splats.poll()
        assert not bpy.ops.splat.convert_from_blender_splats.poll()
    assert not operators.default_blender_splats()


@pytest.mark.skipif(HAS_53, reason="this bpy has Gaussian splat point clouds")
def test_before_53_importer_option_fails_clearly(tmp_path, rng):
    path = tmp_path / "a.ply"
    splat_io.save(random_gaussians(rng, 10, degree=0), path)
    before = bs.scene_state()
    with pytest.raises(data.BlenderSplatsUnsupported):
        operators.import_splats(path, blender_splats=True)
    assert bs.scene_state() == before
    with pytest.raises(RuntimeError, match="5.3"):  # the operator's error report
        bpy.ops.splat.import_splats(filepath=str(path), representation="BLENDER")
    assert bs.scene_state() == before
    bpy.ops.splat.import_splats(filepath=str(path))  # the default: the add-on's object
    assert splat_object.is_splat_object(bpy.context.active_object)


def test_sized_pointcloud_keeps_nothing_of_the_mesh():
    pointcloud = data._sized_pointcloud("P", 7)
    assert len(pointcloud.points) == 7 and pointcloud.name == "P"
    assert not any(a.name.startswith(".select") for a in pointcloud.attributes)
    assert "P" not in bpy.data.meshes and "P" not in bpy.data.objects


def test_read_a_cloud_equals_the_convention(rng, stand_in):
    g = random_gaussians(rng, 300, degree=3)
    obj = _stand_in_cloud(g)
    assert any_splats.is_splat_source(obj)
    back = data.read_gaussians(obj.data)
    expected = attributes.gaussians_from_attributes(attributes.attributes_from_gaussians(g)).gaussians
    assert bs.gaussians_equal(back, expected)


def test_gather_takes_blender_splats_with_their_transform(rng, stand_in):
    g = random_gaussians(rng, 200, degree=2)
    obj = _stand_in_cloud(g)
    obj.location = (1, 2, 3)
    obj.rotation_euler = (0.3, -0.2, 1.0)
    obj.scale = (2, 2, 2)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    result = gather.gather(depsgraph)
    assert len(result.batches) == 1 and result.batches[0].name == obj.name
    local = data.read_gaussians(obj.data)
    want = transform_gaussians(local, np.array(obj.matrix_world, np.float64))
    np.testing.assert_array_equal(result.gaussians.means, want.means)
    np.testing.assert_array_equal(result.gaussians.sh, want.sh)
    again = gather.gather(bpy.context.evaluated_depsgraph_get())
    assert again.cache_hits == 1
    # handed back to Blender's renderer: the add-on leaves it out (export still takes it)
    obj.splat.render_by_blender = True
    assert gather.gather(bpy.context.evaluated_depsgraph_get()).batches == []
    assert len(gather.gather(bpy.context.evaluated_depsgraph_get(), objects=[obj],
                             include_blender_rendered=True).batches) == 1


def test_gather_sees_an_edit_of_the_cloud(rng, stand_in):
    obj = _stand_in_cloud(random_gaussians(rng, 50, degree=0))
    first = gather.gather(bpy.context.evaluated_depsgraph_get()).gaussians.means.copy()
    position = obj.data.attributes["position"]
    values = np.empty(150, np.float32)
    position.data.foreach_get("vector", values)
    values[0] += 1.0
    position.data.foreach_set("vector", values)
    obj.data.update_tag()
    second = gather.gather(bpy.context.evaluated_depsgraph_get()).gaussians.means
    assert second[0, 0] != first[0, 0]


def test_export_of_a_blender_cloud_equals_its_data(rng, stand_in, tmp_path):
    g = random_gaussians(rng, 120, degree=3)
    obj = _stand_in_cloud(g)
    obj.matrix_world = bs.bpy.context.scene.cursor.matrix  # identity
    bpy.context.view_layer.objects.active = obj
    path = tmp_path / "out.ply"
    operators.export_splats(obj, path, forward_axis="Y", up_axis="Z")
    written = splat_io.load(path)
    assert bs.gaussians_equal(written, data.read_gaussians(obj.data))
    with bpy.context.temp_override(active_object=obj, object=obj):
        assert bpy.ops.splat.export_splats.poll()


def test_crop_select_and_clean_up_take_blender_clouds(rng, stand_in):
    g = random_gaussians(rng, 400, degree=1)
    obj = _stand_in_cloud(g)
    obj.data.attributes.new("user_tag", "FLOAT", "POINT").data.foreach_set("value", np.arange(400, dtype=np.float32))
    obj.location = (0.5, 0, 0)
    for other in bpy.context.view_layer.objects:
        other.select_set(False)
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj
    world = g.means.astype(np.float64) + [0.5, 0, 0]
    inside = np.all(np.abs(world) <= 1.0, axis=1)
    assert bpy.ops.splat.crop(shape="BOX", center=(0, 0, 0), size=(2, 2, 2)) == {"FINISHED"}
    assert any_splats.point_count(obj) == inside.sum()
    tags = np.empty(int(inside.sum()), np.float32)
    obj.data.attributes["user_tag"].data.foreach_get("value", tags)
    np.testing.assert_array_equal(tags, np.flatnonzero(inside).astype(np.float32))
    assert data.is_blender_splat_object(obj)
    kept = data.read_gaussians(obj.data)
    np.testing.assert_array_equal(kept.means, g.means[inside])

    assert bpy.ops.splat.select_by(criterion="OPACITY", compare="BELOW", threshold=0.5) == {"FINISHED"}
    opacity = 1 / (1 + np.exp(-kept.opacity_logits.astype(np.float64)))
    np.testing.assert_array_equal(any_splats.selection(obj), opacity < 0.5)
    assert bpy.ops.splat.clean_up(use_size=False, use_isolated=False, min_opacity=0.2) == {"FINISHED"}
    assert any_splats.point_count(obj) == int((opacity >= 0.2).sum())


def test_ownership_hides_blender_splats_from_blenders_rays(stand_in, rng, monkeypatch):
    monkeypatch.setattr(data, "supported", lambda: True)
    obj = _stand_in_cloud(random_gaussians(rng, 10, degree=0))
    obj.visible_shadow = False  # the user's own choice survives the round trip
    ownership.sync_scene(bpy.context.scene)
    assert not any(getattr(obj, name) for name in ownership.RAY_VISIBILITY)
    assert obj.display_type == "BOUNDS" and not obj.hide_render
    obj.splat.render_by_blender = True  # the update callback gives it back
    assert obj.visible_camera and obj.visible_diffuse and not obj.visible_shadow
    assert obj.display_type == "TEXTURED" and ownership.SAVED not in obj
    obj.splat.render_by_blender = False
    assert not obj.visible_camera and obj.display_type == "BOUNDS"


def test_a_saved_file_keeps_blenders_own_state_and_the_add_on_takes_it_again(
        stand_in, rng, monkeypatch, tmp_path):
    monkeypatch.setattr(data, "supported", lambda: True)
    obj = _stand_in_cloud(random_gaussians(rng, 10, degree=0))
    obj.visible_shadow = False  # the user's own choice
    scene = bpy.context.scene
    ownership.sync_scene(scene)
    bridge.ensure_bridge(scene)
    assert ownership.RENDER_MODIFIER in obj.modifiers and obj.display_type == "BOUNDS"
    path = tmp_path / "saved.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path), copy=True)
    # in this session the add-on owns it again ...
    assert ownership.RENDER_MODIFIER in obj.modifiers and not obj.visible_camera
    assert obj.display_type == "BOUNDS" and ownership.SAVED in obj
    assert bridge.bridge_node(scene) is not None
    # ... while the file holds the object as Blender made it, and the scene without the bridge:
    # Blender renders its own splats there (read linked: no handler touches them)
    with bpy.data.libraries.load(str(path), link=True) as (source, target):
        target.objects = [obj.name]
        target.scenes = [scene.name]
    (saved,), (saved_scene,) = target.objects, target.scenes
    assert saved.library is not None and len(saved.modifiers) == 0
    assert saved.visible_camera and saved.visible_diffuse and not saved.visible_shadow
    assert saved.display_type == "TEXTURED"
    assert ownership.SAVED not in saved and ownership.DISPLAY_SAVED not in saved
    assert bridge.bridge_node(saved_scene) is None


def test_a_scene_with_the_add_ons_own_splats_is_saved_with_its_bridge(
        stand_in, rng, monkeypatch, tmp_path):
    monkeypatch.setattr(data, "supported", lambda: True)
    _stand_in_cloud(random_gaussians(rng, 10, degree=0))
    splat_object.create_splat_object(random_gaussians(rng, 10, degree=0), "Ours")
    scene = bpy.context.scene
    bridge.ensure_bridge(scene)
    path = tmp_path / "mixed.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path), copy=True)
    with bpy.data.libraries.load(str(path), link=True) as (source, target):
        target.scenes = [scene.name]
    assert bridge.bridge_node(target.scenes[0]) is not None  # a Blender without it must refuse


def test_render_modifier_empties_the_cloud_for_blender_but_not_for_gather(stand_in, rng, monkeypatch):
    monkeypatch.setattr(data, "supported", lambda: True)
    g = random_gaussians(rng, 40, degree=1)
    obj = _stand_in_cloud(g)
    ownership.sync_scene(bpy.context.scene)
    modifier = obj.modifiers[ownership.RENDER_MODIFIER]
    assert modifier.show_render and not modifier.show_viewport and ownership.reads_original(obj)
    modifier.show_viewport = True  # what a final render evaluates (empty in 5.3: splats53.py)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    result = gather.gather(depsgraph, use_cache=False)
    assert len(result.gaussians) == 40  # the object's own data, with its matrix
    np.testing.assert_array_equal(result.gaussians.means, g.means)
    # a modifier of the user's own: the add-on must read the evaluated cloud, so it steps aside
    obj.modifiers.new("Mine", "NODES")
    ownership.sync_object(obj, bpy.context.scene)
    assert ownership.RENDER_MODIFIER not in obj.modifiers and not obj.visible_camera
    obj.modifiers.clear()
    ownership.sync_object(obj, bpy.context.scene)
    assert ownership.RENDER_MODIFIER in obj.modifiers
    obj.splat.render_by_blender = True
    assert len(obj.modifiers) == 0


def test_convert_to_mesh_takes_a_blender_cloud(stand_in):
    from addon.blender import mesh_convert
    from scenes import sphere_gaussians

    obj = _stand_in_cloud(sphere_gaussians(1.0, 1500, 0.07), "Ball")
    obj.location = (2.0, 0.0, 1.0)
    new = mesh_convert.convert_to_mesh(obj, cameras="SPHERE", resolution=24, max_triangles=600,
                                       texture_size=64, view_count=16, view_size=48)
    assert new.type == "MESH" and len(new.data.polygons) > 0
    centre = np.mean([new.matrix_world @ v.co for v in new.data.vertices], axis=0)
    np.testing.assert_allclose(centre, (2.0, 0.0, 1.0), atol=0.1)  # the cloud's transform applies
