"""Splats that move with Blender's deform stack (addon/blender/sources/own.py, deformed.py
through addon/core/deform): shapes and SH follow the deformation, not only the centres.

- The issue's bent row: 41 splats elongated along x (scale 0.08 x 0.012 x 0.012), a Simple
  Deform bending the row by 180 degrees about Z, an orthographic camera from above: with the
  centres alone (the deformation switched off, as before) the arc draws as a ladder of
  horizontal dashes and some pixel rows along its vertical stretch are empty; with the
  Gaussians bent too, none is.
- A rigid bone rotation (an armature parented with automatic weights): the render from the
  camera moved with the bone equals the render before, view-dependent SH colour included.
- Analytic deformations (a bend and a twist, as shape keys holding the exact deformed
  positions): the render equals the render of the float64 reference Gaussians (analytic centres,
  analytic J Sigma J^T, SH by J's polar rotation), median over the covered pixels <= 1/255.
"""

from __future__ import annotations

import bpy_support as bs
from bpy_support import bpy  # the shared bpy import
import mathutils
import numpy as np
import pytest

import reference_deform
from addon.blender import splat_object
from addon.blender.sources import deformed, gather, own
from addon.core.gaussians import Gaussians
from addon.core.render.renderer import render
from scenes import random_gaussians

COVERED = 0.1  # alpha above which a pixel counts as covered by splats


def row_of_dashes() -> Gaussians:
    n = 41
    means = np.zeros((n, 3))
    means[:, 0] = (np.arange(n) - (n - 1) / 2) * 0.05
    return Gaussians(means, np.log(np.tile([0.08, 0.012, 0.012], (n, 1))),
                     np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)), np.full(n, 3.0),
                     np.full((n, 1, 3), 1.0))


def empty_rows_along_the_arc(camera_obj) -> float:
    """The fraction of pixel rows between the highest and lowest projected centre where no
    pixel is covered by more than half."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    result = gather.gather(depsgraph, use_cache=False)
    camera = bs.camera_of(camera_obj, depsgraph)
    image = render(result.gaussians, camera, threads=1)
    centres = result.gaussians.means.astype(np.float64)
    view = centres @ camera.world_to_camera[:3, :3].T + camera.world_to_camera[:3, 3]
    rows = camera.fy * view[:, 1] + camera.cy
    top, bottom = int(np.ceil(rows.min())), int(np.floor(rows.max()))
    return float((image.alpha[top:bottom].max(axis=1) < 0.5).mean())


def test_the_bent_row_renders_as_one_continuous_arc(monkeypatch):
    bs.reset_scene()
    obj = splat_object.create_splat_object(row_of_dashes(), "Row")
    camera = bs.add_camera(location=(0.0, 0.3, 5.0), rotation=(0.0, 0.0, 0.0), width=160,
                           height=160)
    camera.data.type, camera.data.ortho_scale = "ORTHO", 2.0
    bend = obj.modifiers.new("Bend", "SIMPLE_DEFORM")
    bend.deform_method, bend.deform_axis, bend.angle = "BEND", "Z", np.pi
    bent = empty_rows_along_the_arc(camera)
    with monkeypatch.context() as patch:  # before: the centres alone followed the bend
        patch.setattr(own.OwnObject, "rest_data", lambda self: None)
        centres_only = empty_rows_along_the_arc(camera)
    print(f"empty rows along the arc: {centres_only:.1%} with the centres alone, {bent:.1%} bent")
    assert centres_only > 0.05
    assert bent == 0.0


def test_no_deformation_reads_the_object_as_before(rng, monkeypatch):
    """Without modifiers, shape keys or a deforming parent nothing extra runs, and a stack that
    moves nothing changes nothing."""
    bs.reset_scene()
    g = random_gaussians(rng, 200, 2)
    obj = splat_object.create_splat_object(g, "Splats")
    monkeypatch.setattr(deformed, "deform", lambda *a, **k: pytest.fail("deformed without a stack"))
    result = gather.gather(bpy.context.evaluated_depsgraph_get(), use_cache=False)
    assert bs.gaussians_equal(result.gaussians, g)
    obj.modifiers.new("Nothing", "SIMPLE_DEFORM").angle = 0.0
    result = gather.gather(bpy.context.evaluated_depsgraph_get(), use_cache=False)
    assert bs.gaussians_equal(result.gaussians, g)


def armature_over(obj):
    """A one-bone armature (head at the origin, along +Z) parented to `obj` with automatic
    weights."""
    rig = bpy.data.objects.new("Rig", bpy.data.armatures.new("Rig"))
    bpy.context.scene.collection.objects.link(rig)
    bpy.context.view_layer.objects.active = rig
    bpy.ops.object.mode_set(mode="EDIT")
    bone = rig.data.edit_bones.new("Bone")
    bone.head, bone.tail = (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)
    bpy.ops.object.mode_set(mode="OBJECT")
    for other in bpy.context.scene.objects:
        other.select_set(False)
    obj.select_set(True)
    rig.select_set(True)
    assert bpy.ops.object.parent_set(type="ARMATURE_AUTO") == {"FINISHED"}
    return rig


def covered_median(a: np.ndarray, b: np.ndarray, alpha_a: np.ndarray, alpha_b: np.ndarray) -> float:
    covered = (alpha_a > COVERED) | (alpha_b > COVERED)
    assert covered.mean() > 0.1
    return float(np.median(np.abs(a - b).max(axis=-1)[covered]))


def test_a_rigid_bone_rotation_keeps_the_colour_seen_from_the_same_relative_direction(rng):
    bs.reset_scene()
    g = random_gaussians(rng, 1500, 3, radius=0.5, centre=(0.0, 0.0, 0.6), stray=0.0)
    g = Gaussians(g.means, g.log_scales - 1.0, g.quats, np.abs(g.opacity_logits) + 1.0,
                  g.sh * 2.0)  # smaller, opaque, strongly view-dependent
    obj = splat_object.create_splat_object(g, "Splats")
    rig = armature_over(obj)
    camera = bs.add_camera(location=(0.4, -3.0, 1.0), rotation=(np.radians(85), 0.0, 0.1),
                           width=96, height=96)
    before = bs.render_scene(camera, use_cache=False)
    turn = mathutils.Euler((0.5, -0.3, 0.9)).to_quaternion()
    rig.pose.bones["Bone"].rotation_mode = "QUATERNION"
    rig.pose.bones["Bone"].rotation_quaternion = turn
    bpy.context.view_layer.update()
    # the camera moved with the bone sees each Gaussian from the same relative direction
    pose = rig.pose.bones["Bone"]
    motion = rig.matrix_world @ pose.matrix @ pose.bone.matrix_local.inverted()
    camera.matrix_world = motion @ camera.matrix_world
    bpy.context.view_layer.update()
    after = bs.render_scene(camera, use_cache=False)
    error = covered_median(before.rgb, after.rgb, before.alpha, after.alpha)
    print(f"median colour change over the covered pixels: {error:.2e}")
    assert error <= 1.0 / 255.0
    with pytest.MonkeyPatch.context() as patch:  # the SH left unrotated would change it
        patch.setattr(own.OwnObject, "rest_data", lambda self: None)
        centres_only = bs.render_scene(camera, use_cache=False)
    assert covered_median(before.rgb, centres_only.rgb, before.alpha, centres_only.alpha) \
        > 4.0 / 255.0


@pytest.mark.parametrize("field", ["bend", "twist"])
def test_an_analytic_deformation_renders_as_its_float64_reference(rng, field):
    bs.reset_scene()
    axis = np.arange(-0.3, 0.3 + 1e-9, 0.03)
    rest = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    rest = rest + rng.uniform(-0.2, 0.2, rest.shape) * 0.03
    g = random_gaussians(rng, len(rest), 2)
    g = Gaussians(rest, np.log(rng.uniform(0.006, 0.02, (len(rest), 3))), g.quats,
                  np.abs(g.opacity_logits), g.sh)
    moved, jac = (reference_deform.bend(g.means, 0.5) if field == "bend"
                  else reference_deform.twist(g.means, 2.0))
    obj = splat_object.create_splat_object(g, "Splats")
    obj.shape_key_add(name="Basis")
    key = obj.shape_key_add(name=field)
    key.data.foreach_set("co", moved.astype(np.float32).reshape(-1))
    key.value = 1.0
    camera = bs.add_camera(location=(0.1, -2.2, 0.3), rotation=(np.radians(85), 0.0, 0.05),
                           width=96, height=96)
    got = bs.render_scene(camera, use_cache=False)
    truth = Gaussians(moved, g.log_scales, g.quats, g.opacity_logits, g.sh)
    truth = reference_deform.deformed(truth, jac,
                                      np.stack([reference_deform.polar(j) for j in jac]))
    want = render(truth, bs.camera_of(camera, bpy.context.evaluated_depsgraph_get()), threads=1)
    error = covered_median(got.rgb, want.rgb, got.alpha, want.alpha)
    with pytest.MonkeyPatch.context() as patch:  # the centres alone are far from it
        patch.setattr(own.OwnObject, "rest_data", lambda self: None)
        centres_only = bs.render_scene(camera, use_cache=False)
    before = covered_median(centres_only.rgb, want.rgb, centres_only.alpha, want.alpha)
    print(f"{field}: median colour error over the covered pixels {error:.2e} "
          f"({before:.2e} with the centres alone)")
    assert error <= 1.0 / 255.0 < before
