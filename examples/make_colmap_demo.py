"""Builds examples/demo_colmap/, the small COLMAP scene the README's demo imports and trains on.

A procedural Blender scene (textured ground, a monkey, a few textured primitives, a sun) is
rendered with Cycles on the CPU from 30 cameras on two rings around it; the images go to
`demo_colmap/images/` as JPEG, and a COLMAP model of the *known* cameras goes to
`demo_colmap/sparse/0/` (binary), with sparse points triangulated by pycolmap from SIFT
matches with those poses held fixed (features, exhaustive matching, `triangulate_points`).

Like a real reconstruction, the model lives in its own frame: the Blender world (Z up) is
mapped into COLMAP's frame by a fixed similarity (`COLMAP_FROM_BLENDER` below, Y down and an
arbitrary scale and offset), so importing with `align=True` has work to do.
`demo_colmap/known_poses.json` records the truth: each image's Blender camera-to-world matrix
and intrinsics, and that similarity.

`--sfm` also runs pycolmap's incremental mapping on the images (no poses given) and compares
the recovered camera centres with the known ones after a similarity alignment, relative to the
scene size (the camera rig's diameter); `tests/core/colmap/test_colmap_demo.py` runs the same check.

    .venv/bin/python examples/make_colmap_demo.py            # render, write, triangulate
    .venv/bin/python examples/make_colmap_demo.py --sfm      # ... and check SfM against truth
    .venv/bin/python examples/make_colmap_demo.py --sfm-only # only the check, on what is there

The output is deterministic up to Cycles' and SIFT's floating point; it is a few MB.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sys
import tempfile
import time
from typing import TYPE_CHECKING
from pathlib import Path

import numpy as np

if TYPE_CHECKING:  # the annotations only; both are imported where used
    import bpy
    import pycolmap

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from addon.core.cameras import BlenderCameraParams, Camera, camera_from_blender  # noqa: E402

OUT = ROOT / "examples" / "demo_colmap"
WIDTH, HEIGHT = 480, 360
SAMPLES = 16
JPEG_QUALITY = 92
RINGS = ((20, 5.0, 1.9), (10, 3.8, 3.6))  # (cameras, radius, height) of each ring
TARGET = (0.0, 0.0, 0.6)
LENS_MM, SENSOR_MM = 30.0, 36.0


def _colmap_from_blender() -> np.ndarray:
    """A fixed similarity from the Blender world into the model's frame (x' = s R x + t)."""
    yaw, tilt, scale = math.radians(37.0), math.radians(-103.0), 0.41
    rz = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]])
    rx = np.array([[1, 0, 0], [0, math.cos(tilt), -math.sin(tilt)], [0, math.sin(tilt), math.cos(tilt)]])
    m = np.eye(4)
    m[:3, :3] = scale * (rx @ rz)
    m[:3, 3] = (0.8, -1.3, 3.1)
    return m


COLMAP_FROM_BLENDER = _colmap_from_blender()


# -- the Blender scene ---------------------------------------------------------------------------

def _material(bpy, name: str, build) -> "bpy.types.Material":
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = nodes["Principled BSDF"]
    coord = nodes.new("ShaderNodeTexCoord")
    build(nodes, links, coord, bsdf)
    return mat


def _ground(nodes, links, coord, bsdf):
    # Non-repeating texture (SIFT matches need distinct neighbourhoods): tiles of varied tints
    # from a Voronoi pattern, modulated by two scales of noise.
    vor = nodes.new("ShaderNodeTexVoronoi")
    vor.inputs["Scale"].default_value = 2.5
    noise = nodes.new("ShaderNodeTexNoise")
    noise.inputs["Scale"].default_value = 3.0
    noise.inputs["Detail"].default_value = 10.0
    fine = nodes.new("ShaderNodeTexNoise")
    fine.inputs["Scale"].default_value = 25.0
    fine.inputs["Detail"].default_value = 4.0
    mix = nodes.new("ShaderNodeMix")
    mix.data_type = "RGBA"
    mix.blend_type = "MULTIPLY"
    mix.inputs["Factor"].default_value = 0.7
    grain = nodes.new("ShaderNodeMix")
    grain.data_type = "RGBA"
    grain.blend_type = "OVERLAY"
    grain.inputs["Factor"].default_value = 0.5
    for tex in (vor, noise, fine):
        links.new(coord.outputs["Object"], tex.inputs["Vector"])
    links.new(vor.outputs["Color"], mix.inputs["A"])
    links.new(noise.outputs["Color"], mix.inputs["B"])
    links.new(mix.outputs["Result"], grain.inputs["A"])
    links.new(fine.outputs["Color"], grain.inputs["B"])
    links.new(grain.outputs["Result"], bsdf.inputs["Base Color"])
    bsdf.inputs["Roughness"].default_value = 0.8


def _voronoi(scale, tint):
    def build(nodes, links, coord, bsdf):
        vor = nodes.new("ShaderNodeTexVoronoi")
        vor.inputs["Scale"].default_value = scale
        ramp = nodes.new("ShaderNodeValToRGB")
        ramp.color_ramp.elements[0].color = (0.05, 0.05, 0.08, 1)
        ramp.color_ramp.elements[1].color = (*tint, 1)
        noise = nodes.new("ShaderNodeTexNoise")
        noise.inputs["Scale"].default_value = 14.0
        mix = nodes.new("ShaderNodeMix")
        mix.data_type = "RGBA"
        mix.blend_type = "OVERLAY"
        mix.inputs["Factor"].default_value = 0.6
        links.new(coord.outputs["Object"], vor.inputs["Vector"])
        links.new(coord.outputs["Object"], noise.inputs["Vector"])
        links.new(vor.outputs["Color"], mix.inputs["A"])
        links.new(noise.outputs["Color"], mix.inputs["B"])
        links.new(mix.outputs["Result"], ramp.inputs["Fac"])
        links.new(vor.outputs["Color"], bsdf.inputs["Base Color"])
        links.new(mix.outputs["Result"], bsdf.inputs["Base Color"])
        bsdf.inputs["Roughness"].default_value = 0.5
    return build


def _bricks(nodes, links, coord, bsdf):
    brick = nodes.new("ShaderNodeTexBrick")
    brick.inputs["Scale"].default_value = 4.0
    brick.inputs["Color1"].default_value = (0.8, 0.25, 0.1, 1)
    brick.inputs["Color2"].default_value = (0.9, 0.75, 0.3, 1)
    links.new(coord.outputs["Object"], brick.inputs["Vector"])
    links.new(brick.outputs["Color"], bsdf.inputs["Base Color"])


def build_scene(bpy):
    """The procedural scene in the current (factory-reset) Blender session."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    mats = {
        "ground": _material(bpy, "ground", _ground),
        "monkey": _material(bpy, "monkey", _voronoi(7.0, (0.2, 0.6, 0.9))),
        "sphere": _material(bpy, "sphere", _voronoi(11.0, (0.9, 0.3, 0.6))),
        "bricks": _material(bpy, "bricks", _bricks),
        "column": _material(bpy, "column", _voronoi(5.0, (0.4, 0.9, 0.3))),
    }

    def add(op, material, **kwargs):
        op(**kwargs)
        obj = bpy.context.active_object
        obj.data.materials.append(mats[material])
        return obj

    add(bpy.ops.mesh.primitive_plane_add, "ground", size=7.0)
    monkey = add(bpy.ops.mesh.primitive_monkey_add, "monkey", size=1.5, location=(0, 0, 0.75))
    monkey.rotation_euler = (math.radians(-10), 0, math.radians(20))
    mod = monkey.modifiers.new("subsurf", "SUBSURF")
    mod.levels = mod.render_levels = 1
    bpy.ops.object.shade_smooth()
    add(bpy.ops.mesh.primitive_uv_sphere_add, "sphere", radius=0.45, location=(1.6, -0.9, 0.45))
    bpy.ops.object.shade_smooth()
    add(bpy.ops.mesh.primitive_cube_add, "bricks", size=0.8, location=(-1.5, -1.1, 0.4),
        rotation=(0, 0, math.radians(30)))
    add(bpy.ops.mesh.primitive_cylinder_add, "column", radius=0.3, depth=1.6,
        location=(-0.9, 1.6, 0.8))
    bpy.ops.object.shade_smooth()
    add(bpy.ops.mesh.primitive_cube_add, "bricks", size=0.6, location=(1.4, 1.5, 0.3),
        rotation=(0, 0, math.radians(-15)))

    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    sun.data.energy = 3.5
    sun.data.angle = math.radians(8)
    sun.rotation_euler = (math.radians(40), math.radians(15), math.radians(30))
    scene.collection.objects.link(sun)
    world = bpy.data.worlds.new("world")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.55, 0.65, 0.8, 1)
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.8
    scene.world = world

    render = scene.render
    render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = SAMPLES
    scene.cycles.use_denoising = True
    scene.cycles.max_bounces = 2
    render.resolution_x, render.resolution_y, render.resolution_percentage = WIDTH, HEIGHT, 100
    render.image_settings.file_format = "JPEG"
    render.image_settings.quality = JPEG_QUALITY
    scene.view_settings.view_transform = "Standard"
    return scene


def ring_cameras(bpy, scene) -> list:
    """The camera objects, in image order (name = image name without extension)."""
    import mathutils

    cameras = []
    target = mathutils.Vector(TARGET)
    index = 0
    for ring, (count, radius, height) in enumerate(RINGS):
        for k in range(count):
            angle = 2 * math.pi * (k + 0.5 * ring) / count
            eye = mathutils.Vector((radius * math.cos(angle), radius * math.sin(angle), height))
            data = bpy.data.cameras.new(f"cam{index:03d}")
            data.lens, data.sensor_width, data.sensor_fit = LENS_MM, SENSOR_MM, "HORIZONTAL"
            obj = bpy.data.objects.new(f"{index:03d}", data)
            obj.rotation_euler = (target - eye).to_track_quat("-Z", "Y").to_euler()
            obj.location = eye
            scene.collection.objects.link(obj)
            cameras.append(obj)
            index += 1
    bpy.context.view_layer.update()
    return cameras


def known_camera(obj, scene) -> Camera:
    cam, render = obj.data, scene.render
    return camera_from_blender(BlenderCameraParams(
        matrix_world=np.array(obj.matrix_world, dtype=np.float64), lens=cam.lens,
        sensor_width=cam.sensor_width, sensor_height=cam.sensor_height,
        sensor_fit=cam.sensor_fit, shift_x=cam.shift_x, shift_y=cam.shift_y,
        resolution_x=render.resolution_x, resolution_y=render.resolution_y,
        resolution_percentage=render.resolution_percentage,
        pixel_aspect_x=render.pixel_aspect_x, pixel_aspect_y=render.pixel_aspect_y))


# -- COLMAP ----------------------------------------------------------------------------------

def to_colmap_frame(camera: Camera) -> np.ndarray:
    """cam_from_world (3x4) of `camera` in the model's frame (see COLMAP_FROM_BLENDER)."""
    s = np.cbrt(np.linalg.det(COLMAP_FROM_BLENDER[:3, :3]))
    r = COLMAP_FROM_BLENDER[:3, :3] / s
    t = COLMAP_FROM_BLENDER[:3, 3]
    rc, tc = camera.world_to_camera[:3, :3], camera.world_to_camera[:3, 3]
    # x_cam = rc x + tc with x = r^T (x' - t) / s; scaled by s: rc r^T x' + (s tc - rc r^T t)
    rot = rc @ r.T
    return np.concatenate([rot, (s * tc - rot @ t)[:, None]], axis=1)


def write_model(names: list[str], cameras: list[Camera], image_dir: Path, model_dir: Path,
                work: Path) -> "pycolmap.Reconstruction":
    """Features and exhaustive matches of the images, then points triangulated with the known
    poses and intrinsics held fixed; written to `model_dir` as .bin."""
    import pycolmap

    database = work / "database.db"
    cam = cameras[0]
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "PINHOLE"
    reader.camera_params = ",".join(repr(v) for v in (cam.fx, cam.fy, cam.cx, cam.cy))
    pycolmap.extract_features(database, image_dir, image_names=names,
                              camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader,
                              device=pycolmap.Device.cpu)
    pycolmap.match_exhaustive(database, device=pycolmap.Device.cpu)

    rec = pycolmap.Reconstruction()
    with pycolmap.Database.open(database) as db:
        db_cameras = db.read_all_cameras()
        db_images = {im.name: im for im in db.read_all_images()}
    assert len(db_cameras) == 1
    camera = db_cameras[0]
    rec.add_camera_with_trivial_rig(camera)
    for name, known in zip(names, cameras):
        assert (known.fx, known.fy, known.cx, known.cy, known.width, known.height) == \
            (cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height)
        db_image = db_images[name]
        image = pycolmap.Image(name=name, camera_id=camera.camera_id, image_id=db_image.image_id)
        pose = to_colmap_frame(known)
        image.points2D = pycolmap.Point2DList()
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(pose))
    (work / "triangulated").mkdir()
    rec = pycolmap.triangulate_points(rec, database, image_dir, work / "triangulated")
    rec = compact(rec)
    model_dir.mkdir(parents=True, exist_ok=True)
    rec.write_binary(str(model_dir))
    return rec


def compact(rec) -> "pycolmap.Reconstruction":
    """The same model keeping only the 2D points that observe a 3D point (COLMAP keeps every
    keypoint in images.bin: most of the file, and of no use to an importer)."""
    import pycolmap

    out = pycolmap.Reconstruction()
    for camera in rec.cameras.values():
        out.add_camera_with_trivial_rig(camera)
    index = {}
    for im in sorted(rec.images.values(), key=lambda im: im.name):
        kept = im.get_observation_point2D_idxs()
        xy = np.array([im.points2D[i].xy for i in kept], np.float64).reshape(-1, 2)
        index.update({(im.image_id, i): k for k, i in enumerate(kept)})
        out.add_image_with_trivial_frame(
            pycolmap.Image(name=im.name, keypoints=xy, camera_id=im.camera_id,
                           image_id=im.image_id), im.cam_from_world())
    for _, point in sorted(rec.points3D.items()):
        track = pycolmap.Track()
        for el in point.track.elements:
            track.add_element(el.image_id, index[(el.image_id, el.point2D_idx)])
        out.add_point3D(point.xyz, track, point.color)
    out.update_point_3d_errors()
    return out


def camera_centres_from_model(rec) -> dict[str, np.ndarray]:
    return {im.name: im.projection_center() for im in rec.images.values() if im.has_pose}


def sfm_check(out: Path = OUT, *, verbose: bool = True) -> dict:
    """Runs pycolmap SfM on `out/images` and compares camera centres with known_poses.json.

    Returns {"seconds", "registered", "total", "max_error", "mean_error"} with errors relative
    to the scene size (the largest distance between two known camera centres).
    """
    import pycolmap

    known = json.loads((out / "known_poses.json").read_text())
    names = sorted(known["images"])
    truth = {n: np.array(known["images"][n]["camera_to_world"])[:3, 3] for n in names}
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        database = work / "database.db"
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = "PINHOLE"
        pycolmap.extract_features(database, out / "images", image_names=names,
                                  camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader,
                                  device=pycolmap.Device.cpu)
        pycolmap.match_exhaustive(database, device=pycolmap.Device.cpu)
        models = pycolmap.incremental_mapping(database, out / "images", work / "sparse")
    seconds = time.perf_counter() - start
    if not models:
        raise RuntimeError("pycolmap registered no images")
    rec = max(models.values(), key=lambda r: r.num_reg_images())
    found = camera_centres_from_model(rec)
    common = [n for n in names if n in found]
    src = np.array([found[n] for n in common])
    tgt = np.array([truth[n] for n in common])
    sim = pycolmap.estimate_sim3d(src, tgt)
    if sim is None:
        raise RuntimeError("no similarity between the SfM and the known camera centres")
    aligned = sim * src
    errors = np.linalg.norm(aligned - tgt, axis=1)
    all_truth = np.array(list(truth.values()))
    size = max(np.linalg.norm(a - b) for a in all_truth for b in all_truth)
    result = {"seconds": seconds, "registered": len(common), "total": len(names),
              "max_error": float(errors.max() / size), "mean_error": float(errors.mean() / size)}
    if verbose:
        print(f"SfM: {result['registered']}/{result['total']} images registered in "
              f"{seconds:.1f} s; camera centres vs known poses after a similarity: "
              f"mean {100 * result['mean_error']:.3f} %, max {100 * result['max_error']:.3f} % "
              f"of the scene size ({size:.2f} Blender units)")
    return result


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument("--sfm", action="store_true", help="also check pycolmap SfM against truth")
    parser.add_argument("--sfm-only", action="store_true", help="only the SfM check")
    args = parser.parse_args(argv)
    out: Path = args.out
    if args.sfm_only:
        sfm_check(out)
        return

    import bpy

    start = time.perf_counter()
    scene = build_scene(bpy)
    cameras = ring_cameras(bpy, scene)
    if out.exists():
        shutil.rmtree(out)
    (out / "images").mkdir(parents=True)
    names, known = [], []
    for obj in cameras:
        scene.camera = obj
        name = f"{obj.name}.jpg"
        scene.render.filepath = str(out / "images" / name)
        bpy.ops.render.render(write_still=True)
        names.append(name)
        known.append(known_camera(obj, scene))
    rendered = time.perf_counter() - start
    print(f"rendered {len(names)} images at {WIDTH}x{HEIGHT} in {rendered:.1f} s")

    with tempfile.TemporaryDirectory() as tmp:
        rec = write_model(names, known, out / "images", out / "sparse" / "0", Path(tmp))
    print(f"model: {rec.num_reg_images()} images, {rec.num_points3D()} points, "
          f"mean reprojection error {rec.compute_mean_reprojection_error():.3f} px "
          f"({time.perf_counter() - start - rendered:.1f} s)")
    (out / "known_poses.json").write_text(json.dumps({
        "about": "Ground truth of the demo scene: Blender world (Z up) camera-to-world matrices "
                 "(Blender camera frame: -Z forward, +Y up), pinhole intrinsics in pixels "
                 "(pixel centres at i + 0.5), and the similarity colmap_from_blender that maps "
                 "the Blender world into the COLMAP model's frame (x' = M x).",
        "colmap_from_blender": COLMAP_FROM_BLENDER.tolist(),
        "images": {
            name: {"camera_to_world": np.array(obj.matrix_world).tolist(),
                   "fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy,
                   "width": c.width, "height": c.height}
            for name, obj, c in zip(names, cameras, known)},
    }, indent=1))
    if args.sfm:
        sfm_check(out)


if __name__ == "__main__":
    main()
