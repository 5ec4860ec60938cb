"""Runs inside a real Blender with the extension installed (for this user, as on an artist's
machine): builds a farm test scene and saves it where the farm reads it.

    blender -b --python farm_scene.py -- anim SPLATS.npz OUT.blend
    blender -b --python farm_scene.py -- rig SPLATS.npz OUT.blend
    blender -b --python farm_scene.py -- sequence FRAMES_PATTERN OUT.blend
    blender -b --python farm_scene.py -- splats53 SPLATS.ply OUT.blend     (Blender 5.3 and later)

`anim`: random splats about the origin, a red cube in front, a blue plane behind, a camera that
moves over frames 1-6 (64x48, Cycles on the CPU, emission materials). `sequence`: the same meshes
and a still camera, and a splat sequence (one file per frame, FRAMES_PATTERN such as
`.../frames/walk_####.ply`) stored relative to the .blend, so a worker that sees the .blend and its
`frames/` folder in shared storage reads the same files. `rig`: the `anim` splats and meshes, a
still camera, the splat object parented to a two-bone armature (Object > Parent > With Empty
Groups, then smooth weights from the splats' heights), the upper bone turning over frames 1-6:
the splats bend at the joint, their shapes and SH with them. `splats53`: the `anim` scene with the
splats imported by Blender's own PLY importer (a point cloud of type 'GAUSSIAN_SPLAT', which the
add-on renders). All start, as generation scripts do, by emptying the file
(`bpy.data.objects.remove` of every object). Then the settings Flamenco's add-on evaluates for
"Simple Blender Render" are printed as one JSON line (`FARM_SETTINGS {...}`).
"""

from __future__ import annotations

import importlib
import json
import os
import sys

import bpy
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # scene_kit, copied beside this
import scene_kit  # noqa: E402

ADDON = "bl_ext.user_default.gaussian_splatting"


def _empty_file() -> None:
    for obj in list(bpy.data.objects):
        bpy.data.objects.remove(obj)


def _render_settings(scene) -> None:
    scene_kit.render_settings(scene, threads=1, frames=(1, 6))  # two workers share two cores
    scene.splat_render.threads = 1


def flamenco_settings(scene) -> dict:
    """What Flamenco's add-on evaluates for "Simple Blender Render" (its job type's `eval`s)."""
    return {
        "frames": f"{scene.frame_start}-{scene.frame_end}",
        "fps": scene.render.fps / scene.render.fps_base,
        "format": scene.render.image_settings.file_format,
        "image_file_extension": scene.render.file_extension,
        "has_previews": bool(getattr(scene.render.image_settings, "use_preview", False)),
        "scene": scene.name,
    }


def _rig(obj) -> None:
    """A two-bone armature along Z (Lower from z = -1.2 to 0, Upper from 0 to 1.2) that `obj` is
    parented to With Empty Groups, each splat weighted by its height (Upper's weight rising
    smoothly from 0 at z = -0.5 to 1 at z = 0.5, Lower's the rest); Upper turns from its rest
    pose at frame 1 to (0.9, 0, 0.4) radians at frame 6."""
    scene = bpy.context.scene
    rig = bpy.data.objects.new("Rig", bpy.data.armatures.new("Rig"))
    scene.collection.objects.link(rig)
    bpy.context.view_layer.objects.active = rig
    bpy.ops.object.mode_set(mode="EDIT")
    lower = rig.data.edit_bones.new("Lower")
    lower.head, lower.tail = (0.0, 0.0, -1.2), (0.0, 0.0, 0.0)
    upper = rig.data.edit_bones.new("Upper")
    upper.head, upper.tail = (0.0, 0.0, 0.0), (0.0, 0.0, 1.2)
    upper.parent, upper.use_connect = lower, True
    bpy.ops.object.mode_set(mode="OBJECT")
    for other in scene.objects:
        other.select_set(other in (obj, rig))
    assert bpy.ops.object.parent_set(type="ARMATURE_NAME") == {"FINISHED"}
    assert obj.parent == rig and any(m.type == "ARMATURE" for m in obj.modifiers)
    z = np.empty(len(obj.data.vertices) * 3, np.float32)
    obj.data.vertices.foreach_get("co", z)
    t = np.clip(z[2::3] + 0.5, 0.0, 1.0)
    weights = t * t * (3.0 - 2.0 * t)
    for index, weight in enumerate(weights.tolist()):
        obj.vertex_groups["Upper"].add([index], weight, "REPLACE")
        obj.vertex_groups["Lower"].add([index], 1.0 - weight, "REPLACE")
    pose = rig.pose.bones["Upper"]
    pose.rotation_mode = "XYZ"
    for frame, angles in ((1, (0.0, 0.0, 0.0)), (6, (0.9, 0.0, 0.4))):
        pose.rotation_euler = angles
        pose.keyframe_insert("rotation_euler", frame=frame)


def main(kind: str, source: str, out: str) -> None:
    addon = importlib.import_module(ADDON)
    if not hasattr(bpy.types.Scene, "splat_render"):
        addon.register()
    bpy.ops.wm.read_homefile(use_empty=False)
    _empty_file()
    scene = bpy.context.scene
    camera = scene_kit.meshes_and_camera(bpy, scene)
    _render_settings(scene)
    os.makedirs(os.path.dirname(out), exist_ok=True)
    if kind in ("anim", "splats53"):
        for frame, x, z in ((1, -0.8, -0.3), (6, 0.8, 0.4)):   # the camera moves
            camera.location = (x, -6.0, z)
            camera.keyframe_insert("location", frame=frame)
    if kind in ("anim", "rig"):
        gaussians_mod = importlib.import_module(ADDON + ".core.gaussians")
        splat_object = importlib.import_module(ADDON + ".blender.splat_object")
        data = np.load(source)
        g = gaussians_mod.Gaussians(data["means"], data["log_scales"], data["quats"],
                                    data["opacity_logits"], data["sh"])
        obj = splat_object.create_splat_object(g, "Splats")
        if kind == "rig":
            _rig(obj)
    elif kind == "splats53":
        bpy.ops.wm.ply_import(filepath=source)
        splats = bpy.context.active_object
        assert splats.type == "POINTCLOUD" and splats.data.type == "GAUSSIAN_SPLAT", splats
        importlib.import_module(ADDON + ".blender.blender_splats.ownership").sync_scene(scene)
    elif kind == "sequence":
        operators = importlib.import_module(ADDON + ".blender.io.operators")
        bpy.ops.wm.save_as_mainfile(filepath=out)           # a home for the relative path
        obj = operators.import_sequence(source, relative=True)   # "Relative Path", the default
        assert obj.splat.sequence_source.startswith("//"), obj.splat.sequence_source
    else:
        raise SystemExit(f"unknown scene kind {kind!r}")
    bpy.ops.object.select_all(action="DESELECT")
    bpy.ops.wm.save_as_mainfile(filepath=out)
    print("FARM_SETTINGS " + json.dumps(flamenco_settings(scene)), flush=True)


if __name__ == "__main__":
    main(*sys.argv[sys.argv.index("--") + 1:])
