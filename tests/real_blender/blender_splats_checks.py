"""Blender 5.3's own splat point clouds with only the extension installed: the checks of issue 24.

Run by scripts/test_installed_extension.py's `blender_splats` stage (a clean bpy 5.3+, the zip
installed and enabled, a fresh user folder); plain bpy, numpy and the installed extension's own
modules (OpenImageIO from its wheels reads the PNGs), nothing from this project, so the same
file runs in real Blender too. `run_all(bpy, check, work, data)`; `check(name)` is a context
manager that prints PASS/FAIL (scripts/test_installed_extension.py's `Check`).

  Blender's PLY importer     playbot through `bpy.ops.wm.ply_import`: a point cloud of type
                             'GAUSSIAN_SPLAT' holding every Gaussian of the file.
  F12 of Blender's splats    Cycles, a cube in front and a plane behind, 4 samples, SIZE: the
                             frame with Blender's object equals the frame with the add-on's own
                             object of the same file (its importer, placed as Blender's object)
                             within 1/255 at the median and 3/255 at the 99th percentile of the
                             pixels' largest channel error, shows the splats, and takes at most
                             3 times as long (medians of 3 F12s each, after one each to warm up).
  export                     the add-on's exporter on Blender's object, to .ply with the axes
                             Blender's importer used: the file's Gaussians equal the source's
                             within 1e-4 (positions, log scales, unit quaternions up to sign,
                             opacities after the sigmoid, SH).
  conversion round trips     every file of ../shared/data/splats: the add-on's object -> Blender's
                             -> the add-on's, and Blender's -> the add-on's -> Blender's (the
                             Object menu's operators), equal up to float32 rounding of exp/log and
                             sigmoid/logit; and for the files Blender reads itself (.ply, .spz),
                             Blender's importer's object -> the add-on's -> Blender's.
"""

from __future__ import annotations

import importlib
import math
import time
from pathlib import Path

EXTENSION = "bl_ext.user_default.gaussian_splatting"
SIZE = (320, 240)
PLAYBOT = "playbot_125k_sh2.ply"
FILES = (PLAYBOT, "guitar.compressed.ply", "biker.spz", "chair.splat",
         "playbot_sog/lod-meta.json")
BLENDER_READS = {".ply": "ply_import", ".spz": "spz_import"}  # bpy.ops.wm.*
TIME_RATIO = 3.0
EXPORT_TOLERANCE = 1e-4


def ext(name: str):
    return importlib.import_module(f"{EXTENSION}.{name}")


def run_all(bpy, check, work: Path, data: Path) -> None:
    splats = data / "splats"
    blender_obj = None
    with check("Blender's PLY importer makes a splat point cloud") as c:
        blender_obj = blender_import(bpy, splats / PLAYBOT)
        c.detail = f"{len(blender_obj.data.points)} points, matrix {matrix_text(blender_obj)}"
    with check("F12 of Blender's splats (Cycles, a mesh in front) = the add-on's own") as c:
        assert blender_obj is not None, "no Blender splat object"
        c.detail = f12_check(bpy, blender_obj, splats / PLAYBOT, work)
    with check("export of Blender's splat object to .ply = the source file") as c:
        assert blender_obj is not None, "no Blender splat object"
        c.detail = export_check(bpy, blender_obj, splats / PLAYBOT, work)
    for name in FILES:
        with check(f"conversion round trips: {name}") as c:
            c.detail = round_trips(bpy, splats / name)


# ----------------------------------------------------------------------------- helpers

def clear_scene(bpy) -> None:
    for collection in (bpy.data.objects, bpy.data.meshes, bpy.data.pointclouds,
                       bpy.data.materials, bpy.data.cameras, bpy.data.images):
        for item in list(collection):
            collection.remove(item)


def new_object(bpy, run):
    before = set(bpy.data.objects)
    result = run()
    assert result == {"FINISHED"}, result
    (obj,) = set(bpy.data.objects) - before
    return obj


def blender_import(bpy, path: Path):
    """Blender's own importer (its defaults)."""
    operator = getattr(bpy.ops.wm, BLENDER_READS[path.suffix])
    obj = new_object(bpy, lambda: operator(filepath=str(path)))
    assert obj.type == "POINTCLOUD" and obj.data.type == "GAUSSIAN_SPLAT", \
        f"{path.name}: Blender's importer made a {obj.type} ({getattr(obj.data, 'type', '')})"
    return obj


def addon_import(bpy, path: Path, **axes):
    return new_object(bpy, lambda: bpy.ops.splat.import_splats(
        filepath=str(path), representation="ADDON", **axes))


def matrix_text(obj) -> str:
    rows = [[round(v, 3) + 0.0 for v in row] for row in obj.matrix_world]
    return "identity" if rows == [[float(i == j) for j in range(4)] for i in range(4)] \
        else str(rows)


def select_only(bpy, obj) -> None:
    for other in bpy.context.view_layer.objects:
        other.select_set(False)
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj


# ---------------------------------------------------------------------------------- F12

def build_scene(bpy, splats_obj):
    """A cube in front of the splats, a plane behind, a camera looking along +Y (as the
    installed-extension render stage), Cycles at 4 samples."""
    import numpy as np
    from mathutils import Vector

    import scene_kit  # tests/real_blender, on sys.path

    scene = bpy.context.scene
    corners = np.array([splats_obj.matrix_world @ Vector(c) for c in splats_obj.bound_box])
    low, high = corners.min(axis=0), corners.max(axis=0)
    centre, radius = (low + high) / 2, float(np.linalg.norm(high - low)) / 2
    bpy.ops.mesh.primitive_cube_add(size=0.35 * radius, location=(
        centre[0] + 0.25 * radius, low[1] - 0.4 * radius, centre[2]))
    bpy.context.active_object.data.materials.append(
        scene_kit.material(bpy, "Cube", (0.9, 0.3, 0.1)))
    bpy.ops.mesh.primitive_plane_add(size=20 * radius, location=(
        centre[0], high[1] + 0.5 * radius, centre[2]), rotation=(math.pi / 2, 0, 0))
    bpy.context.active_object.data.materials.append(
        scene_kit.material(bpy, "Plane", (0.1, 0.35, 0.8)))
    camera = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(camera)
    camera.location = (centre[0], centre[1] - 2.2 * radius, centre[2])
    camera.rotation_euler = (math.pi / 2, 0, 0)
    camera.data.lens = 35
    scene.camera = camera
    render = scene.render
    render.resolution_x, render.resolution_y = SIZE
    render.resolution_percentage = 100
    render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 4
    scene.cycles.use_denoising = False
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.max_bounces = 0
    view = scene.view_settings
    view.view_transform, view.look, view.exposure, view.gamma = "Standard", "None", 0.0, 1.0
    render.dither_intensity = 0.0
    settings = render.image_settings
    if hasattr(settings, "media_type"):
        settings.media_type = "IMAGE"
    settings.file_format, settings.color_mode, settings.color_depth = "PNG", "RGBA", "8"
    return scene


def f12(bpy, scene, path: Path) -> float:
    scene.render.filepath = str(path)
    start = time.perf_counter()
    assert bpy.ops.render.render(write_still=True) == {"FINISHED"}
    return time.perf_counter() - start


def read_png(path: Path):
    import numpy as np
    import OpenImageIO as oiio  # the extension's wheel

    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    buf = oiio.ImageBuf(str(path), 0, 0, config)
    if buf.has_error:
        raise OSError(f"{path}: {buf.geterror()}")
    return np.asarray(buf.get_pixels(oiio.UINT8), np.int32)


def f12_check(bpy, blender_obj, path: Path, work: Path) -> str:
    import numpy as np

    ours = addon_import(bpy, path, forward_axis="Y", up_axis="Z")
    ours.matrix_world = blender_obj.matrix_world.copy()
    scene = build_scene(bpy, blender_obj)
    objects = {"blender": blender_obj, "ours": ours}

    def show(which: str | None) -> None:
        for key, obj in objects.items():
            obj.hide_render = key != which

    show(None)
    f12(bpy, scene, work / "splats53_meshes.png")
    times = {"blender": [], "ours": []}
    for which in ("blender", "ours"):  # the first F12 of each reads its splats
        show(which)
        f12(bpy, scene, work / f"splats53_{which}.png")
    for _ in range(3):
        for which in ("blender", "ours"):
            show(which)
            times[which].append(f12(bpy, scene, work / f"splats53_{which}.png"))
    theirs_png, ours_png = (read_png(work / f"splats53_{w}.png") for w in ("blender", "ours"))
    meshes = read_png(work / "splats53_meshes.png")
    error = np.abs(theirs_png - ours_png).max(axis=-1)
    median, p99 = float(np.median(error)), float(np.percentile(error, 99))
    seen = int(np.abs(ours_png[..., :3] - meshes[..., :3]).max())
    t_blender, t_ours = (sorted(times[w])[1] for w in ("blender", "ours"))
    detail = (f"{SIZE[0]}x{SIZE[1]}: median {median:.0f}/255, p99 {p99:.0f}/255, max "
              f"{int(error.max())}/255; F12 {t_blender * 1000:.0f} ms (Blender's object) vs "
              f"{t_ours * 1000:.0f} ms (the add-on's), ratio {t_blender / t_ours:.2f}")
    assert seen > 20, f"no splats in the add-on's own frame ({detail})"
    assert median <= 1 and p99 <= 3, f"the frames differ: {detail}"
    assert t_blender <= TIME_RATIO * t_ours, f"too slow: {detail}"
    for obj in (ours,):
        bpy.data.objects.remove(obj)
    show("blender")
    return detail


# ------------------------------------------------------------------------------- export

def comparable(gaussians):
    """What renders: positions, log scales, unit quaternions (w >= 0), opacities, SH."""
    import numpy as np

    quats = gaussians.quats / np.linalg.norm(gaussians.quats, axis=1, keepdims=True)
    quats = np.where(quats[:, :1] < 0, -quats, quats)
    opacity = 1 / (1 + np.exp(-gaussians.opacity_logits.astype(np.float64)))
    return {"means": gaussians.means, "log_scales": gaussians.log_scales, "quats": quats,
            "opacity": opacity, "sh": gaussians.sh}


def differences(a, b) -> dict[str, float]:
    import numpy as np

    first, second = comparable(a), comparable(b)
    assert len(a) == len(b), f"{len(a)} Gaussians against {len(b)}"
    out = {}
    for key in first:
        x, y = np.asarray(first[key], np.float64), np.asarray(second[key], np.float64)
        assert x.shape == y.shape, f"{key}: shape {x.shape} against {y.shape}"
        out[key] = float(np.abs(x - y).max()) if x.size else 0.0
    return out


def blender_import_axes(bpy, blender_obj) -> dict[str, str]:
    """The axis options that undo Blender's PLY importer's object matrix (its defaults)."""
    props = bpy.ops.wm.ply_import.get_rna_type().properties
    return {"forward_axis": props["forward_axis"].default,
            "up_axis": props["up_axis"].default}


def export_check(bpy, blender_obj, path: Path, work: Path) -> str:
    registry = ext("core.formats.registry")
    select_only(bpy, blender_obj)
    axes = blender_import_axes(bpy, blender_obj)
    target = work / "blender_splats_export.ply"
    result = bpy.ops.splat.export_splats(filepath=str(target), **axes)
    assert result == {"FINISHED"}, result
    source, _ = registry.read(path)
    written, _ = registry.read(target)
    diff = differences(source, written)
    worst = max(diff.values())
    detail = (f"axes {axes['forward_axis']}/{axes['up_axis']}, {len(written)} Gaussians, "
              + ", ".join(f"{k} {v:.1e}" for k, v in diff.items()))
    assert worst <= EXPORT_TOLERANCE, detail
    return detail


# ---------------------------------------------------------------------- round trips

# Float32 rounding of what the conversion computes (exp/log of scales, sigmoid/logit of
# opacities, compared after the sigmoid); positions, quaternions and SH are copied.
ROUND_TRIP = {"means": 0.0, "log_scales": 1e-5, "quats": 1e-7, "opacity": 1e-6, "sh": 0.0}


def local_gaussians(obj):
    """Every Gaussian of `obj` in its own space (hidden ones too), whichever kind it is."""
    return ext("blender.blender_splats.any_splats").object_gaussians(obj, drop_hidden=False)


def convert(bpy, obj, to_blender: bool):
    select_only(bpy, obj)
    operator = (bpy.ops.splat.convert_to_blender_splats if to_blender
                else bpy.ops.splat.convert_from_blender_splats)
    new = new_object(bpy, lambda: operator(keep_original=True))
    is_blender = new.type == "POINTCLOUD" and new.data.type == "GAUSSIAN_SPLAT"
    assert is_blender == to_blender, f"the conversion made a {new.type}"
    assert [list(r) for r in new.matrix_world] == [list(r) for r in obj.matrix_world], \
        "the transform did not carry over"
    return new


def same(a, b, what: str) -> float:
    diff = differences(a, b)
    bad = {k: v for k, v in diff.items() if v > ROUND_TRIP[k]}
    assert not bad, f"{what}: {bad}"
    return max(diff.values())


def round_trips(bpy, path: Path) -> str:
    clear_scene(bpy)
    ours = addon_import(bpy, path)
    original = local_gaussians(ours)
    theirs = convert(bpy, ours, to_blender=True)
    back = convert(bpy, theirs, to_blender=False)
    worst = same(original, local_gaussians(back), "ours -> Blender's -> ours")
    again = convert(bpy, back, to_blender=True)
    worst = max(worst, same(local_gaussians(theirs), local_gaussians(again),
                            "Blender's -> ours -> Blender's"))
    detail = f"{len(original)} Gaussians (SH degree {original.degree})"
    if path.suffix in BLENDER_READS:
        clear_scene(bpy)
        imported = blender_import(bpy, path)
        first = local_gaussians(imported)
        via_ours = convert(bpy, convert(bpy, imported, to_blender=False), to_blender=True)
        worst = max(worst, same(first, local_gaussians(via_ours),
                                "Blender's importer -> ours -> Blender's"))
        detail += ", and from Blender's importer"
    clear_scene(bpy)
    return f"{detail}; largest difference {worst:.1e}"
