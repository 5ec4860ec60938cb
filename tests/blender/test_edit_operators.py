"""Crop, Select By and Clean Up on splat objects (bpy), checked against the same measures
computed directly with numpy from the Gaussians the object was made of."""

from __future__ import annotations

import bpy_support as bs
from bpy_support import bpy  # the shared bpy import
import numpy as np
import pytest

from addon.blender import edit_operators, splat_object
from addon.blender.sources import gather
from addon.core.cleanup import floater_masks, sigmoid
from addon.core.gaussians import Gaussians
from scenes import random_gaussians


@pytest.fixture(autouse=True)
def empty_scene():
    bs.reset_scene()
    yield
    gather.clear_cache()


def make_object(g: Gaussians, name: str = "Splats"):
    obj = splat_object.create_splat_object(g, name)
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    return obj


def transformed_object(rng, n=400, degree=2):
    g = random_gaussians(rng, n, degree)
    obj = make_object(g)
    obj.location = (1.0, -0.5, 0.25)
    obj.rotation_euler = (0.2, 0.4, -0.3)
    obj.scale = (1.5, 1.5, 1.5)
    bpy.context.view_layer.update()
    return g, obj


def world_means(g: Gaussians, obj) -> np.ndarray:
    m = np.array(obj.matrix_world, dtype=np.float64)
    return g.means.astype(np.float64) @ m[:3, :3].T + m[:3, 3]


def selection(obj) -> np.ndarray:
    selected = np.zeros(len(obj.data.vertices), bool)
    obj.data.vertices.foreach_get("select", selected)
    return selected


# ------------------------------------------------------------------------------------ crop

@pytest.mark.parametrize("shape", ["BOX", "SPHERE"])
@pytest.mark.parametrize("invert", [False, True])
def test_crop_with_center_and_size(rng, shape, invert):
    g, obj = transformed_object(rng)
    center, size, radius = (1.0, -0.5, 0.5), (3.0, 2.0, 4.0), 2.2
    assert bpy.ops.splat.crop(shape=shape, center=center, size=size, radius=radius,
                              invert=invert) == {"FINISHED"}
    p = world_means(g, obj)
    if shape == "BOX":
        inside = np.all(np.abs(p - center) <= np.array(size) / 2, axis=1)
    else:
        inside = np.linalg.norm(p - center, axis=1) <= radius
    keep = ~inside if invert else inside
    assert 0 < keep.sum() < len(g)
    assert bs.gaussians_equal(bs.mesh_gaussians(obj), g.subset(keep))


def test_crop_to_a_volume_object_keeps_other_attributes(rng):
    g, obj = transformed_object(rng)
    weights = rng.random(len(g)).astype(np.float32)
    obj.data.attributes.new("my_weight", "FLOAT", "POINT").data.foreach_set("value", weights)
    colors = rng.random((len(g), 4)).astype(np.float32)
    obj.data.color_attributes.new("tint", "FLOAT_COLOR", "POINT").data.foreach_set(
        "color", colors.ravel())
    for display, volume_shape in (("CUBE", "BOX"), ("SPHERE", "SPHERE")):
        volume = bpy.data.objects.new(f"volume_{display}", None)
        volume.empty_display_type = display
        volume.empty_display_size = 1.0
        bpy.context.scene.collection.objects.link(volume)
        volume.location = (0.5, 0.0, 0.0)
        volume.rotation_euler = (0.0, 0.3, 0.8)
        volume.scale = (2.0, 1.0, 1.5)
        bpy.context.view_layer.update()
        before = bs.mesh_gaussians(obj)
        local = (world_means(before, obj) - np.array(volume.location)) @ \
            np.linalg.inv(np.array(volume.matrix_world)[:3, :3]).T
        keep = (np.all(np.abs(local) <= 1.0, axis=1) if volume_shape == "BOX"
                else np.linalg.norm(local, axis=1) <= 1.0)
        bpy.ops.splat.crop(shape=volume_shape, volume=volume.name)
        assert bs.gaussians_equal(bs.mesh_gaussians(obj), before.subset(keep))
        weights, colors = weights[keep], colors[keep]
    assert len(obj.data.vertices) > 0
    got = np.empty(len(obj.data.vertices), np.float32)
    obj.data.attributes["my_weight"].data.foreach_get("value", got)
    assert np.array_equal(got, weights)
    got = np.empty(len(obj.data.vertices) * 4, np.float32)
    obj.data.attributes["tint"].data.foreach_get("color", got)
    assert np.array_equal(got.reshape(-1, 4), colors)


def test_crop_takes_a_selected_object_as_volume(rng):
    g, obj = transformed_object(rng)
    bpy.ops.object.empty_add(type="CUBE", location=(1.0, -0.5, 0.25))
    cube = bpy.context.active_object
    cube.scale = (1.0, 1.0, 1.0)
    obj.select_set(True)
    bpy.context.view_layer.objects.active = cube  # splat selected, volume active
    bpy.ops.splat.crop(shape="BOX", invert=False)
    p = world_means(g, obj)
    assert bs.gaussians_equal(bs.mesh_gaussians(obj),
                              g.subset(np.all(np.abs(p - (1.0, -0.5, 0.25)) <= 1.0, axis=1)))
    assert cube.name in bpy.data.objects


def test_crop_mesh_with_edges_goes_through_bmesh(rng):
    g = random_gaussians(rng, 100, 1)
    obj = make_object(g)
    obj.data.edges.add(1)
    obj.data.edges[0].vertices = (0, 1)
    obj.data.update()
    bpy.ops.splat.crop(shape="SPHERE", center=(0, 0, 0), radius=1.5)
    keep = np.linalg.norm(g.means, axis=1) <= 1.5
    assert bs.gaussians_equal(bs.mesh_gaussians(obj), g.subset(keep))


def test_crop_in_edit_mode_returns_to_edit_mode(rng):
    g = random_gaussians(rng, 100, 0)
    obj = make_object(g)
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.splat.crop(shape="BOX", center=(0, 0, 0), size=(2, 2, 2))
    assert obj.mode == "EDIT"
    bpy.ops.object.mode_set(mode="OBJECT")
    keep = np.all(np.abs(g.means) <= 1.0, axis=1)
    assert bs.gaussians_equal(bs.mesh_gaussians(obj), g.subset(keep))


def test_crop_errors_leave_the_object_alone(rng):
    g = random_gaussians(rng, 20, 0)
    obj = make_object(g)
    with pytest.raises(RuntimeError, match="No object named"):
        bpy.ops.splat.crop(volume="nothing")
    assert bs.gaussians_equal(bs.mesh_gaussians(obj), g)


# ------------------------------------------------------------------------------- select by

def test_select_by_opacity_size_and_distance(rng):
    g, obj = transformed_object(rng)
    scene = bpy.context.scene
    scene.cursor.location = (0.5, 0.5, 0.0)
    opacity = sigmoid(g.opacity_logits)
    size = np.exp(g.log_scales.max(axis=1).astype(np.float64)) * 1.5
    distance = np.linalg.norm(world_means(g, obj) - (0.5, 0.5, 0.0), axis=1)

    bpy.ops.splat.select_by(criterion="OPACITY", compare="BELOW", threshold=0.3)
    want = opacity < 0.3
    assert np.array_equal(selection(obj), want)
    bpy.ops.splat.select_by(criterion="SIZE", compare="ABOVE", threshold=0.1, action="EXTEND")
    want |= size > 0.1
    assert np.array_equal(selection(obj), want)
    bpy.ops.splat.select_by(criterion="DISTANCE", compare="BELOW", threshold=2.0,
                            action="SUBTRACT")
    want &= ~(distance < 2.0)
    assert np.array_equal(selection(obj), want)
    assert 0 < want.sum() < len(g)


def test_select_by_in_edit_mode_skips_hidden(rng):
    g = random_gaussians(rng, 200, 0)
    obj = make_object(g)
    hide = np.zeros(200, bool)
    hide[:50] = True
    obj.data.vertices.foreach_set("select", hide)
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.hide(unselected=False)
    bpy.ops.splat.select_by(criterion="OPACITY", compare="ABOVE", threshold=0.5)
    assert obj.mode == "EDIT"
    assert tuple(bpy.context.tool_settings.mesh_select_mode) == (True, False, False)
    bpy.ops.object.mode_set(mode="OBJECT")
    assert np.array_equal(selection(obj), (sigmoid(g.opacity_logits) > 0.5) & ~hide)


# -------------------------------------------------------------------------------- clean up

def floater_scene(rng) -> tuple[Gaussians, np.ndarray]:
    """A dense cube of splats, plus far floaters, transparent and tiny ones; the mask of what
    the default clean up (radius 0.2) must remove."""
    n_cluster, n_far = 3000, 8
    means = np.concatenate([rng.uniform(-0.5, 0.5, size=(n_cluster, 3)),
                            rng.uniform(5.0, 9.0, size=(n_far, 3)) * np.sign(rng.normal(size=(n_far, 3)))])
    n = len(means)
    log_scales = np.log(0.01) + rng.normal(scale=0.1, size=(n, 3))
    logits = np.full(n, 3.0)
    logits[:6] = -5.0
    log_scales[6:10] = np.log(1e-5)
    g = Gaussians(means, log_scales, rng.normal(size=(n, 4)), logits,
                  rng.normal(size=(n, 1, 3)))
    want = np.zeros(n, bool)
    want[:10] = True
    want[n_cluster:] = True
    return g, want


def test_clean_up_removes_floaters(rng):
    g, want = floater_scene(rng)
    obj = make_object(g)
    obj.scale = (2.0, 2.0, 2.0)  # world space: the radius scales with the object
    masks = edit_operators.find_floaters(obj, radius=0.4)
    assert np.array_equal(masks.any, want)
    assert bpy.ops.splat.clean_up(radius=0.4) == {"FINISHED"}
    assert bs.gaussians_equal(bs.mesh_gaussians(obj), g.subset(~want))


def test_clean_up_select_only_and_preview(rng):
    g, want = floater_scene(rng)
    obj = make_object(g)
    counts = floater_masks(g.means, g.log_scales, g.opacity_logits, radius=0.2).counts()
    assert counts["total"] == want.sum()
    bpy.ops.splat.clean_up(radius=0.2, select_only=True)
    assert np.array_equal(selection(obj), want) and len(obj.data.vertices) == len(g)
    # the dialog's preview: counts for the operator's current settings
    operator_class = bpy.types.SPLAT_OT_clean_up

    class Settings:  # stands in for the operator instance the dialog draws
        use_opacity, min_opacity = True, 0.01
        use_size, min_size_fraction = True, 0.05
        use_isolated, radius, min_neighbours = True, 0.2, 3
        _params = operator_class._params
        _masks = operator_class._masks

    preview = operator_class.preview(Settings(), bpy.context)
    assert preview["total"] == want.sum() and preview["splats"] == len(g)
    assert preview["transparent"] == 6 and preview["tiny"] == 4
