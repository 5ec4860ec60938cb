"""COLMAP scenes in Blender (bpy): the import operator on the real models, re-projection
through the camera objects as Blender computes them, alignment, what the scene holds, and bad
input that must leave the scene as it was.

Blender's projection here is Blender's own: `Object.calc_matrix_camera(depsgraph, x, y,
scale_x, scale_y)` with the camera's recorded render size and pixel aspect, and the object's
`matrix_world` (axes normalised, as `BKE_camera_multiview_model_matrix` does); pixels are
`u = (ndc_x + 1) W / 2`, `v = (1 - ndc_y) H / 2` (see tests/blender/test_cameras_blender.py).
Re-projection errors and import times are printed (`pytest -s`).
"""

from __future__ import annotations

import math
import shutil
import time

import bpy  # slow to import: every bpy-level COLMAP test is in this one module
import numpy as np
import pytest

from addon.blender.io import colmap_import
from addon.core import colmap
from tests.colmap_helpers import colmap_own_residuals


@pytest.fixture(scope="module", autouse=True)
def registered():
    already = hasattr(bpy.types, "SPLAT_OT_import_colmap")
    if not already:
        colmap_import.register()
    yield
    if not already:
        colmap_import.unregister()


_KINDS = ("objects", "cameras", "collections", "images", "meshes", "pointclouds", "materials",
          "actions")


def _snapshot() -> dict[str, set]:
    return {kind: set(getattr(bpy.data, kind)[:]) for kind in _KINDS}


@pytest.fixture
def clean_scene():
    """The context scene; whatever a test adds is removed afterwards."""
    before = _snapshot()
    yield bpy.context.scene
    after = _snapshot()
    for kind in ("objects", "cameras", "meshes", "pointclouds", "materials", "images",
                 "actions", "collections"):
        for block in after[kind] - before[kind]:
            getattr(bpy.data, kind).remove(block)


def _new_collection(before: set) -> bpy.types.Collection:
    new = [c for c in bpy.data.collections if c not in before]
    assert len(new) == 1
    return new[0]


def _cameras(collection) -> list:
    return [o for o in collection.objects if "colmap_image_name" in o]


def blender_pixels(obj, xyz: np.ndarray) -> np.ndarray:
    """Blender's projection of world points through camera object `obj`."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    evaluated = obj.evaluated_get(depsgraph)
    width, height = (int(v) for v in obj["colmap_resolution"])
    percentage = int(obj["colmap_resolution_percentage"])
    width, height = width * percentage // 100, height * percentage // 100
    aspect_x, aspect_y = (float(v) for v in obj["colmap_pixel_aspect"])
    winmat = np.array(evaluated.calc_matrix_camera(depsgraph, x=width, y=height,
                                                   scale_x=aspect_x, scale_y=aspect_y))
    model = np.array(evaluated.matrix_world, dtype=np.float64)
    model[:3, :3] /= np.linalg.norm(model[:3, :3], axis=0)
    clip = np.c_[xyz, np.ones(len(xyz))] @ (winmat @ np.linalg.inv(model)).T
    ndc = clip[:, :2] / clip[:, 3:4]
    return np.stack([(ndc[:, 0] + 1) * width / 2, (1 - ndc[:, 1]) * height / 2], axis=1)


def _point_cloud(collection):
    clouds = [o for o in collection.objects if o.type in ("POINTCLOUD", "MESH")]
    assert len(clouds) == 1
    return clouds[0]


def _attribute(data, name, width=1, dtype=np.float32, field="value"):
    attr = data.attributes[name]
    out = np.zeros(len(attr.data) * width, dtype)
    attr.data.foreach_get(field, out)
    return out.reshape(-1, width) if width > 1 else out


def _blender_residuals(collection, scene: colmap.ColmapScene) -> np.ndarray:
    """Per observation: |Blender's projection of the point cloud's point - observation|."""
    cloud = _point_cloud(collection)
    xyz = _attribute(cloud.data, "position", 3, np.float32, "vector").astype(np.float64)
    ids = _attribute(cloud.data, "colmap_point_id", dtype=np.int32)
    order = np.argsort(ids)
    errors = []
    for obj in _cameras(collection):
        im = scene.image(obj["colmap_image_name"])
        rows = order[np.searchsorted(ids[order], im.point3D_ids)]
        assert (ids[rows] == im.point3D_ids).all()
        errors.append(np.linalg.norm(blender_pixels(obj, xyz[rows]) - im.points2D, axis=1))
    return np.concatenate(errors)


CASES = [  # model, image folder, its scale, through the operator
    ("cup", "images", 1.0, True),
    ("cup", "images_4", 0.25, True),
    ("beer", "images_8", 0.125, True),
    ("beer", "images", 1.0, False),  # cameras only: 71 full-size undistortions are slow
]


@pytest.mark.parametrize("name, folder, scale, operator", CASES)
def test_import_and_reproject_through_blender(shared_data, tmp_path, clean_scene, name, folder,
                                              scale, operator):
    """Every 3D point projected through the Blender camera objects lands where COLMAP's own
    model puts it: the mean error equals COLMAP's own residual (undistorted where the camera
    was). The issue's bound, a mean under 0.5 px, holds at the downscaled folders; at full size
    COLMAP's own residual is above it (cup 0.63 px, beer 0.85 px)."""
    before = set(bpy.data.collections)
    t0 = time.perf_counter()
    if operator:
        result = bpy.ops.splat.import_colmap(directory=str(shared_data / name),
                                             image_folder=folder, align=True,
                                             cache_dir=str(tmp_path))
        assert result == {"FINISHED"}
    else:
        colmap_import.import_colmap(shared_data / name, folder, align=True, cache_dir=tmp_path,
                                    copy_photos=False, backgrounds=False)
    seconds = time.perf_counter() - t0
    collection = _new_collection(before)
    scene = colmap.read_colmap(shared_data / name, folder, cache_dir=tmp_path, align=True,
                               copy_photos=False)
    residual = _blender_residuals(collection, scene)
    own = colmap_own_residuals(shared_data / name / "sparse" / "0")
    theirs = np.concatenate([own[im.name] for im in scene.images]) * scale
    print(f"{name}/{folder}: imported {len(_cameras(collection))} cameras, "
          f"{len(scene.points)} points in {seconds:.2f} s; re-projection through Blender: "
          f"mean {residual.mean():.4f} px, median {np.median(residual):.4f} px, max "
          f"{residual.max():.2f} px (COLMAP's own mean {theirs.mean():.4f} px)")
    assert len(_cameras(collection)) == len(scene.images)
    assert abs(residual.mean() - theirs.mean()) < 0.01 * theirs.mean()
    if scale < 1:
        assert residual.mean() < 0.5


def test_blender_projection_equals_ours(shared_data, tmp_path, clean_scene):
    """The camera objects reproduce our pinhole cameras (float32 rounding only)."""
    before = set(bpy.data.collections)
    bpy.ops.splat.import_colmap(directory=str(shared_data / "beer"), image_folder="images_8",
                                cache_dir=str(tmp_path))
    collection = _new_collection(before)
    scene = colmap.read_colmap(shared_data / "beer", "images_8", cache_dir=tmp_path, align=True)
    worst = 0.0
    for obj in _cameras(collection):
        im = scene.image(obj["colmap_image_name"])
        assert obj["colmap_image_id"] == im.image_id and obj["colmap_camera_id"] == im.camera_id
        assert tuple(obj["colmap_resolution"]) == (im.camera.width, im.camera.height)
        rows = scene.points.positions_of(im.point3D_ids)
        xyz = scene.points.xyz[rows]
        cam = im.camera
        xc = xyz @ cam.world_to_camera[:3, :3].T + cam.world_to_camera[:3, 3]
        ours = np.stack([cam.fx * xc[:, 0] / xc[:, 2] + cam.cx, cam.fy * xc[:, 1] / xc[:, 2] + cam.cy], 1)
        worst = max(worst, np.abs(blender_pixels(obj, xyz) - ours).max())
    print(f"beer/images_8: Blender's projection vs our cameras: worst {worst:.2e} px")
    assert worst < 1e-3


def test_align_in_blender(shared_data, tmp_path, clean_scene):
    """The issue's check on the camera objects: with Up From = camera up vectors the cameras'
    mean up vector is within 5 degrees of +Z. The default (cameras and ground) stands the
    scene on its ground instead; both are printed. The collection's transform maps the
    Blender scene back to COLMAP's frame."""
    import pycolmap

    for name, folder in (("cup", "images_4"), ("beer", "images_8")):
        angles = {}
        for up in ("CAMERAS", "AUTO"):
            before = set(bpy.data.collections)
            bpy.ops.splat.import_colmap(directory=str(shared_data / name), image_folder=folder,
                                        align=True, up_axis=up, cache_dir=str(tmp_path))
            collection = _new_collection(before)
            ups = np.array([np.array(o.matrix_world)[:3, 1] for o in _cameras(collection)])
            mean = ups.mean(axis=0)
            angles[up] = math.degrees(math.acos(mean[2] / np.linalg.norm(mean)))
            transform = np.array(collection["colmap_transform"]).reshape(4, 4)
            cloud = _point_cloud(collection)
            xyz = _attribute(cloud.data, "position", 3, np.float32, "vector").astype(np.float64)
            back = colmap.transform_points(xyz, np.linalg.inv(transform))
            ids = _attribute(cloud.data, "colmap_point_id", dtype=np.int32)
            rec = pycolmap.Reconstruction(str(shared_data / name / "sparse" / "0"))
            want = np.array([rec.points3D[int(i)].xyz for i in ids[::50]])
            assert np.abs(back[::50] - want).max() < 1e-5 * (1 + np.abs(want).max())
            if up == "AUTO":
                assert "ground plane" in collection["colmap_alignment"]
                assert all(o.matrix_world.translation.z > 0 for o in _cameras(collection))
        print(f"{name}: cameras' mean up vector in Blender, from +Z: Up From cameras "
              f"{angles['CAMERAS']:.2f} deg, cameras and ground {angles['AUTO']:.2f} deg")
        assert angles["CAMERAS"] < 5.0


def test_scene_contents(shared_data, tmp_path, clean_scene):
    import pycolmap

    before = set(bpy.data.collections)
    scene = clean_scene
    result = bpy.ops.splat.import_colmap(directory=str(shared_data / "beer"),
                                         image_folder="images_8", align=True,
                                         animated_camera=True, cache_dir=str(tmp_path))
    assert result == {"FINISHED"}
    collection = _new_collection(before)
    cameras = _cameras(collection)
    assert len(cameras) == 71
    assert sorted(o["colmap_image_name"] for o in cameras) == sorted(
        f"{i:04d}.jpg" for i in range(71))
    assert collection["colmap_image_folder"] == "images_8"
    assert len(collection["colmap_missing"].splitlines()) == 42
    assert len(collection["colmap_transform"]) == 16

    # photos as backgrounds where they exist, exactly the undistorted copies
    with_photo = [o for o in cameras if o["colmap_photo"]]
    assert len(with_photo) == 29
    for obj in with_photo:
        (background,) = obj.data.background_images
        assert bpy.path.abspath(background.image.filepath) == obj["colmap_photo"]
        assert tuple(background.image.size) == tuple(obj["colmap_resolution"])
    assert all(len(o.data.background_images) == 0 for o in cameras if not o["colmap_photo"])

    # the point cloud and its attributes
    cloud = _point_cloud(collection)
    assert cloud.type == "POINTCLOUD"
    rec = pycolmap.Reconstruction(str(shared_data / "beer" / "sparse" / "0"))
    ids = _attribute(cloud.data, "colmap_point_id", dtype=np.int32)
    assert len(ids) == rec.num_points3D() == 4414
    colours = _attribute(cloud.data, "color", 4, np.float32, "color_srgb")
    errors = _attribute(cloud.data, "error")
    tracks = _attribute(cloud.data, "track_length", dtype=np.int32)
    for k in range(0, len(ids), 97):
        point = rec.points3D[int(ids[k])]
        np.testing.assert_allclose(colours[k, :3] * 255, point.color, atol=0.51)
        assert errors[k] == pytest.approx(point.error, rel=1e-6)
        assert tracks[k] == point.track.length()

    # the scene camera and its render size
    assert scene.camera in cameras
    assert (scene.render.resolution_x, scene.render.resolution_y) == tuple(scene.camera["colmap_resolution"])
    other = next(o for o in cameras if tuple(o["colmap_resolution"]) != tuple(scene.camera["colmap_resolution"]))
    scene.camera = other
    assert colmap_import.apply_camera_resolution(scene)
    assert (scene.render.resolution_x, scene.render.resolution_y) == tuple(other["colmap_resolution"])

    # the animated camera: frame start + i shows image i (sorted by name)
    (sequence,) = [o for o in collection.objects if o.type == "CAMERA" and "colmap_image_name" not in o]
    by_name = sorted(cameras, key=lambda o: o["colmap_image_name"])
    for i in (0, 17, 70):
        scene.frame_set(scene.frame_start + i)
        target = by_name[i]
        np.testing.assert_allclose(np.array(sequence.matrix_world), np.array(target.matrix_world),
                                   atol=1e-5)
        assert sequence.data.lens == pytest.approx(target.data.lens, rel=1e-6)
        assert sequence.data.shift_x == pytest.approx(target.data.shift_x, abs=1e-6)
    scene.frame_set(scene.frame_start)


def test_bad_input_leaves_the_scene_unchanged(shared_data, tmp_path, clean_scene, monkeypatch):
    work = tmp_path / "beer"
    shutil.copytree(shared_data / "beer" / "sparse" / "0", work / "sparse" / "0")
    (work / "images").mkdir()  # photos of another shape than the model's cameras
    for name in ("0000.jpg", "0001.jpg"):
        shutil.copy(shared_data / "cup" / "images" / "1.jpg", work / "images" / name)
    truncated = tmp_path / "truncated"
    shutil.copytree(work / "sparse" / "0", truncated)
    (truncated / "images.bin").write_bytes((work / "sparse" / "0" / "images.bin").read_bytes()[:999])
    cases = [
        (tmp_path / "nowhere", "images", "no such folder"),
        (tmp_path, "images", "no COLMAP model"),
        (truncated, "images", "corrupt COLMAP binary"),
        (work, "images", "does not fit its camera"),
        (work, "images_2", "none of the photos"),
    ]
    before = _snapshot()
    for directory, folder, message in cases:
        with pytest.raises(RuntimeError, match=message):
            bpy.ops.splat.import_colmap(directory=str(directory), image_folder=folder,
                                        cache_dir=str(tmp_path / "cache"))
        assert _snapshot() == before, directory

    # a failure half way through building removes what was built
    def broken(*args, **kwargs):
        raise RuntimeError("broken on purpose")

    monkeypatch.setattr(colmap_import, "_points_object", broken)
    with pytest.raises(RuntimeError, match="broken on purpose"):
        bpy.ops.splat.import_colmap(directory=str(shared_data / "beer"), image_folder="images_8",
                                    cache_dir=str(tmp_path / "cache"))
    assert _snapshot() == before
