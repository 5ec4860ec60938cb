"""Blender 5.3's splat point clouds bent by a deform stack (issue 35, item 2), in the official
bpy 5.3.0: the `deform` step of splats53.py (staged beside it, plain bpy and the installed
extension).

A point cloud takes no modifier but geometry nodes in 5.3 (Simple Deform, Armature, Lattice...
are refused: `modifiers.new` gives None; no vertex groups, no shape keys; an armature parent
does not deform it), so a stack reaches a cloud through geometry nodes, the two ways
docs/guide/rigging.md gives:

  follow_mesh  a helper mesh of bare vertices at the cloud's points carries the mesh deformers
               (here a Simple Deform, or an armature with automatic weights); a Set Position
               node takes each point to where the helper's vertex of the same index went
  follow_bone  a Bone Info node: each point through the bone's pose against its rest pose

The checks:

  bent row     the issue's row of 41 elongated splats as a Blender splat cloud, bent 180 degrees
               by a Simple Deform (follow_mesh), seen from above through an orthographic camera:
               no empty pixel row along the arc, in the add-on's render of what it gathers and
               in F12 (Cycles, the add-on composing); some with the centres alone.
  bone turn    1500 view-dependent splats turned rigidly by a bone (follow_mesh with an armature,
               and follow_bone), seen by the camera moved with the bone: the colour seen from
               the same relative direction is unchanged (median over covered pixels <= 1/255;
               over 4/255 with the centres alone).
"""

from __future__ import annotations

import math
from pathlib import Path

from extension_kit import check, ext

COVERED = 0.1  # alpha above which a pixel counts as covered by splats


def _gaussians(*arrays):
    return ext("core.gaussians").Gaussians(*arrays)


def row_of_dashes():
    """41 splats along x, each elongated along x (scale 0.08 x 0.012 x 0.012)."""
    import numpy as np

    n = 41
    means = np.zeros((n, 3))
    means[:, 0] = (np.arange(n) - (n - 1) / 2) * 0.05
    return _gaussians(means, np.log(np.tile([0.08, 0.012, 0.012], (n, 1))),
                      np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)), np.full(n, 3.0),
                      np.full((n, 1, 3), 1.0))


def view_dependent_splats(seed: int = 35):
    """1500 small, opaque splats of SH degree 3 with strong view-dependent colour, in a ball of
    radius 0.5 about (0, 0, 0.6)."""
    import numpy as np

    rng = np.random.default_rng(seed)
    n = 1500
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    means = direction * 0.5 * rng.uniform(0, 1, (n, 1)) ** (1 / 3) + (0.0, 0.0, 0.6)
    quats = rng.normal(size=(n, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    sh = rng.normal(0.0, 0.6, (n, 16, 3))
    sh[:, 0] = rng.uniform(-1.0, 1.5, (n, 3))
    return _gaussians(means, np.log(rng.uniform(0.01, 0.03, (n, 3))), quats,
                      rng.uniform(1.5, 4.0, n), sh)


def clear(bpy) -> None:
    for collection in (bpy.data.objects, bpy.data.meshes, bpy.data.pointclouds,
                       bpy.data.armatures, bpy.data.cameras, bpy.data.node_groups):
        for item in list(collection):
            collection.remove(item)
    ext("blender.sources.gather").clear_cache()


def helper_mesh(bpy, means, name: str = "Helper"):
    """A mesh object of bare vertices at `means`, hidden from renders."""
    import numpy as np

    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(len(means))
    mesh.vertices.foreach_set("co", np.asarray(means, np.float32).ravel())
    helper = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(helper)
    helper.hide_render = True
    return helper


def _node_group(bpy, name: str):
    group = bpy.data.node_groups.new(name, "GeometryNodeTree")
    group.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    group.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    return group, group.nodes.new("NodeGroupInput"), group.nodes.new("NodeGroupOutput")


def _set_position(bpy, obj, group, source, out, position) -> None:
    move = group.nodes.new("GeometryNodeSetPosition")
    group.links.new(source.outputs[0], move.inputs["Geometry"])
    group.links.new(position, move.inputs["Position"])
    group.links.new(move.outputs[0], out.inputs[0])
    obj.modifiers.new(group.name, "NODES").node_group = group


def follow_mesh(bpy, obj, helper) -> None:
    """Geometry nodes on `obj`: each point to where `helper`'s evaluated vertex of the same
    index is (Object Info in its original space, Sample Index, Set Position)."""
    group, source, out = _node_group(bpy, "Follow " + helper.name)
    nodes, links = group.nodes, group.links
    info = nodes.new("GeometryNodeObjectInfo")
    info.transform_space = "ORIGINAL"
    info.inputs["Object"].default_value = helper
    sample = nodes.new("GeometryNodeSampleIndex")
    sample.data_type, sample.domain = "FLOAT_VECTOR", "POINT"
    links.new(info.outputs["Geometry"], sample.inputs["Geometry"])
    links.new(nodes.new("GeometryNodeInputPosition").outputs[0], sample.inputs["Value"])
    links.new(nodes.new("GeometryNodeInputIndex").outputs[0], sample.inputs["Index"])
    _set_position(bpy, obj, group, source, out, sample.outputs[0])


def follow_bone(bpy, obj, rig, bone: str) -> None:
    """Geometry nodes on `obj`: each point through the bone's pose against its rest pose
    (Bone Info; `obj` and the armature both at the world's origin)."""
    group, source, out = _node_group(bpy, "Follow " + bone)
    nodes, links = group.nodes, group.links
    info = nodes.new("GeometryNodeBoneInfo")
    info.inputs["Armature"].default_value = rig
    info.inputs["Bone Name"].default_value = bone
    invert = nodes.new("FunctionNodeInvertMatrix")
    links.new(info.outputs["Rest Pose"], invert.inputs["Matrix"])
    motion = nodes.new("FunctionNodeMatrixMultiply")
    links.new(info.outputs["Pose"], motion.inputs[0])
    links.new(invert.outputs["Matrix"], motion.inputs[1])
    point = nodes.new("FunctionNodeTransformPoint")
    links.new(nodes.new("GeometryNodeInputPosition").outputs[0], point.inputs["Vector"])
    links.new(motion.outputs[0], point.inputs["Transform"])
    _set_position(bpy, obj, group, source, out, point.outputs[0])


def one_bone_rig(bpy):
    """A one-bone armature at the origin (the bone along +Z from the origin)."""
    rig = bpy.data.objects.new("Rig", bpy.data.armatures.new("Rig"))
    bpy.context.scene.collection.objects.link(rig)
    bpy.context.view_layer.objects.active = rig
    bpy.ops.object.mode_set(mode="EDIT")
    bone = rig.data.edit_bones.new("Bone")
    bone.head, bone.tail = (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)
    bpy.ops.object.mode_set(mode="OBJECT")
    return rig


def parent_with_automatic_weights(bpy, obj, rig) -> None:
    for other in bpy.context.scene.objects:
        other.select_set(other in (obj, rig))
    bpy.context.view_layer.objects.active = rig
    assert bpy.ops.object.parent_set(type="ARMATURE_AUTO") == {"FINISHED"}
    assert any(m.type == "ARMATURE" for m in obj.modifiers), "no armature modifier"


def add_camera(bpy, location, rotation, width: int, height: int):
    scene = bpy.context.scene
    camera = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(camera)
    camera.location, camera.rotation_euler = location, rotation
    scene.camera = camera
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    return camera


def render_gathered(bpy, camera, *, patched_off: bool = False):
    """The add-on's render (one thread) of what it gathers from the scene, and those
    Gaussians; `patched_off`: with the shapes and SH left at rest (the centres alone)."""
    sources = ext("blender.sources.deformed")
    real = sources.Deformable.rest_data
    if patched_off:
        sources.Deformable.rest_data = lambda self: None
    try:
        depsgraph = bpy.context.evaluated_depsgraph_get()
        result = ext("blender.sources.gather").gather(depsgraph, use_cache=False)
    finally:
        sources.Deformable.rest_data = real
    cam = ext("blender.camera_adapter").camera_of(camera.evaluated_get(depsgraph),
                                                  bpy.context.scene.render)
    image = ext("core.render.renderer").render(result.gaussians, cam, threads=1)
    return image, result.gaussians, cam


def empty_rows(alpha, means, cam) -> float:
    """The fraction of pixel rows between the highest and lowest projected centre where no
    pixel is covered by more than half."""
    import numpy as np

    view = means.astype(np.float64) @ cam.world_to_camera[:3, :3].T + cam.world_to_camera[:3, 3]
    rows = cam.fy * view[:, 1] + cam.cy
    top, bottom = int(np.ceil(rows.min())), int(np.floor(rows.max()))
    return float((alpha[top:bottom].max(axis=1) < 0.5).mean())


def f12_alpha(bpy, work: Path):
    """F12 (flat Cycles, transparent film, the add-on composing), its alpha (H, W) in 0..1."""
    import numpy as np

    import scene_kit

    scene = bpy.context.scene
    scene_kit.flat_cycles(scene)
    scene.render.film_transparent = True
    scene.render.threads_mode, scene.render.threads = "FIXED", 2
    scene_kit.standard_view(scene)
    scene_kit.png_8bit(scene.render.image_settings)
    ext("blender.render.compositor_bridge").ensure_bridge(scene)
    bpy.context.view_layer.update()
    path = work / "deform53_row.png"
    scene.render.filepath = str(path)
    assert bpy.ops.render.render(write_still=True) == {"FINISHED"}
    image = bpy.data.images.load(str(path))
    width, height = image.size
    pixels = np.empty(width * height * 4, np.float32)
    image.pixels.foreach_get(pixels)
    bpy.data.images.remove(image)
    return pixels.reshape(height, width, 4)[::-1, :, 3]  # Blender's rows run bottom up


def check_bent_row(bpy, work: Path) -> None:
    with check("deform: a Blender splat cloud row bent 180 degrees by a Simple Deform "
               "draws one continuous arc") as c:
        clear(bpy)
        row = row_of_dashes()
        cloud = ext("blender.blender_splats.data").create_object(row, "Row")
        helper = helper_mesh(bpy, row.means)
        bend = helper.modifiers.new("Bend", "SIMPLE_DEFORM")
        bend.deform_method, bend.deform_axis, bend.angle = "BEND", "Z", math.pi
        follow_mesh(bpy, cloud, helper)
        ext("blender.blender_splats.ownership").sync_scene(bpy.context.scene)
        camera = add_camera(bpy, (0.0, 0.3, 5.0), (0.0, 0.0, 0.0), 160, 160)
        camera.data.type, camera.data.ortho_scale = "ORTHO", 2.0
        bpy.context.view_layer.update()
        image, gathered, cam = render_gathered(bpy, camera)
        assert cloud.evaluated_get(bpy.context.evaluated_depsgraph_get()).data.type == \
            "GAUSSIAN_SPLAT", "geometry nodes made another point cloud type"
        bent = empty_rows(image.alpha, gathered.means, cam)
        before, _, _ = render_gathered(bpy, camera, patched_off=True)
        centres_only = empty_rows(before.alpha, gathered.means, cam)
        in_f12 = empty_rows(f12_alpha(bpy, work), gathered.means, cam)
        c.detail = (f"empty rows along the arc: {centres_only:.1%} with the centres alone, "
                    f"{bent:.1%} bent, {in_f12:.1%} in F12")
        assert centres_only > 0.05 and bent == 0.0 and in_f12 == 0.0, c.detail


def covered_median(a, b) -> float:
    import numpy as np

    covered = (a.alpha > COVERED) | (b.alpha > COVERED)
    assert covered.mean() > 0.1, f"only {covered.mean():.1%} of the pixels covered"
    return float(np.median(np.abs(a.rgb - b.rgb).max(axis=-1)[covered]))


def check_bone_turn(bpy) -> None:
    import mathutils

    for way in ("a helper mesh with automatic weights", "Bone Info"):
        with check(f"deform: a rigid bone turn of a Blender splat cloud ({way}) keeps the "
                   f"colour seen from the same relative direction") as c:
            clear(bpy)
            splats = view_dependent_splats()
            cloud = ext("blender.blender_splats.data").create_object(splats, "Splats")
            rig = one_bone_rig(bpy)
            if way == "Bone Info":
                follow_bone(bpy, cloud, rig, "Bone")
            else:
                helper = helper_mesh(bpy, splats.means)
                parent_with_automatic_weights(bpy, helper, rig)
                follow_mesh(bpy, cloud, helper)
            ext("blender.blender_splats.ownership").sync_scene(bpy.context.scene)
            camera = add_camera(bpy, (0.4, -3.0, 1.0), (math.radians(85), 0.0, 0.1), 96, 96)
            bpy.context.view_layer.update()
            before, _, _ = render_gathered(bpy, camera)
            pose = rig.pose.bones["Bone"]
            pose.rotation_mode = "QUATERNION"
            pose.rotation_quaternion = mathutils.Euler((0.5, -0.3, 0.9)).to_quaternion()
            bpy.context.view_layer.update()
            motion = rig.matrix_world @ pose.matrix @ pose.bone.matrix_local.inverted()
            camera.matrix_world = motion @ camera.matrix_world
            bpy.context.view_layer.update()
            after, _, _ = render_gathered(bpy, camera)
            centres_only, _, _ = render_gathered(bpy, camera, patched_off=True)
            error, unturned = covered_median(before, after), covered_median(before, centres_only)
            c.detail = (f"median colour change over the covered pixels {error * 255:.2f}/255, "
                        f"{unturned * 255:.1f}/255 with the centres alone")
            assert error <= 1 / 255 and unturned > 4 / 255, c.detail


def check_deform(bpy, work: Path) -> None:
    check_bent_row(bpy, work)
    check_bone_turn(bpy)
