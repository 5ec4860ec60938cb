"""Final renders of splats with meshes (bpy): what Blender writes must be the exact composite.

The scene: random splats about the origin, a cube in front of them, a large plane behind them,
a camera 6 units away; 32x24 pixels (Cycles CPU at 4 samples, or Workbench through software
OpenGL). The expected image is computed here, independently of the add-on's render path: the
same scene is rendered to a multilayer EXR (whose view layer holds Blender's own mesh colour
and depth), the splats are composed with that by `addon.core.render.renderer` (the native compositor),
in display sRGB as docs/conventions.md asks, and the result is encoded as Blender's "Standard" view
transform writes 8-bit PNG. The written file must match it to 1/255.
"""

from __future__ import annotations

import math
import os

import bpy_support as bs
from bpy_support import bpy  # the shared bpy import
import numpy as np
import pytest

from addon.blender import camera_adapter, splat_object
from addon.blender.render import compositor_bridge, hooks, state
from addon.core.images import exr_layers, exr_scanlines
from addon.core.render.composite import compose
from addon.core.render.renderer import render
from real_blender import scene_kit
from scenes import random_gaussians
from standard_view import (decode, encode, native_composite, premultiplied, read_png,
                           standard_8bit)

WIDTH, HEIGHT = 32, 24
ENGINES = ["CYCLES", "BLENDER_WORKBENCH"]


# ---------------------------------------------------------------------------- the scene

def material(name: str, colour, engine: str):
    return scene_kit.material(bpy, name, colour, emission=engine == "CYCLES")


def build_scene(rng, engine: str, *, n: int = 400, meshes: bool = True):
    bs.reset_scene()
    scene = bpy.context.scene
    g = random_gaussians(rng, n, 1, radius=1.0, stray=0.0)
    splats = splat_object.create_splat_object(g, "Splats")
    cube = plane = None
    if meshes:
        bpy.ops.mesh.primitive_cube_add(size=0.9, location=(0.35, -2.5, 0.15))
        cube = bpy.context.active_object
        cube.data.materials.append(material("Cube", (0.9, 0.3, 0.1), engine))
        bpy.ops.mesh.primitive_plane_add(size=40, location=(0, 2.5, 0),
                                         rotation=(math.pi / 2, 0, 0))
        plane = bpy.context.active_object
        plane.data.materials.append(material("Plane", (0.1, 0.35, 0.8), engine))
    camera = bs.add_camera(location=(0.0, -6.0, 0.0), rotation=(math.pi / 2, 0, 0), lens=35,
                           width=WIDTH, height=HEIGHT)
    if engine == "CYCLES":
        scene_kit.flat_cycles(scene)
    else:
        scene.display.shading.color_type = "MATERIAL"
    scene.render.engine = engine
    scene.render.threads_mode = "FIXED"
    scene.render.threads = 2
    scene_kit.standard_view(scene)
    return scene, splats, cube, plane, camera


def render_still(scene, path_prefix, *, multilayer: bool = False):
    settings = scene.render.image_settings
    if multilayer:
        settings.media_type = "MULTI_LAYER_IMAGE"
        settings.color_depth = "32"
    else:
        settings.media_type = "IMAGE"
        settings.file_format = "PNG"
        settings.color_mode = "RGBA"
        settings.color_depth = "8"
    scene.render.filepath = str(path_prefix)
    assert bpy.ops.render.render(write_still=True) == {"FINISHED"}
    return f"{path_prefix}{'.exr' if multilayer else '.png'}"


def save_render_result(scene, path):
    """The last render's Render Result (every layer and pass) as a float multilayer EXR.
    Blender 5.0.1 cannot write a multi-part EXR for non-square pixels, so the pixel aspect is
    set to 1 for the save (the saved pixels do not depend on it)."""
    settings = scene.render.image_settings
    aspect = scene.render.pixel_aspect_x, scene.render.pixel_aspect_y
    media, depth = settings.media_type, settings.color_depth
    settings.media_type, settings.color_depth = "MULTI_LAYER_IMAGE", "32"
    scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
    try:
        bpy.data.images["Render Result"].save_render(str(path), scene=scene)
    finally:
        scene.render.pixel_aspect_x, scene.render.pixel_aspect_y = aspect
        settings.media_type = media
        settings.color_depth = depth
    return path


def mesh_layers(path):
    channels = exr_layers.read_channels(path)
    rgba = exr_layers.find_pass(channels, "ViewLayer", "Combined", "RGBA")
    depth = exr_layers.find_pass(channels, "ViewLayer", "Depth", "Z")[..., 0]
    return rgba, depth, channels


def expected_frame(scene, camera_obj, exr_path):
    mesh_rgba, mesh_depth, channels = mesh_layers(exr_path)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    gaussians = bs.gather.gather(depsgraph).gaussians
    camera = bs.camera_of(camera_obj, depsgraph)
    return native_composite(gaussians, camera, mesh_rgba, mesh_depth), mesh_rgba, channels, \
        gaussians, camera


def assert_close_8bit(written, expected, what=""):
    diff = np.abs(written - expected)
    assert diff.max() <= 1, f"{what}: max error {diff.max()}/255 at {np.unravel_index(diff.argmax(), diff.shape)}"


# ----------------------------------------------------------------------------- the tests

@pytest.mark.parametrize("engine", ENGINES)
def test_still_is_the_exact_composite(rng, tmp_path, engine):
    scene, splats, cube, plane, camera = build_scene(rng, engine)
    png = render_still(scene, tmp_path / "still")
    assert compositor_bridge.bridge_node(scene) is not None  # set up by the render itself
    written = read_png(png)
    # The Render Result (what F12's Image Editor shows and saves) is the composite too.
    bpy.data.images["Render Result"].save_render(str(tmp_path / "shown.png"), scene=scene)
    assert np.abs(read_png(tmp_path / "shown.png") - written).max() <= 1
    exr_path = render_still(scene, tmp_path / "layers", multilayer=True)
    expected, mesh_rgba, channels, gaussians, cam = expected_frame(scene, camera, exr_path)
    assert_close_8bit(written, standard_8bit(expected), engine)

    # The semantics, pixel by pixel: where the cube is, the splats are hidden; where the splats
    # are opaque in front of the plane, the plane is hidden.
    alone = render(gaussians, cam)
    mesh_8 = standard_8bit(mesh_rgba)
    cube_depth = 6.0 - 2.5 - 0.45
    _, depth, _ = mesh_layers(exr_path)
    on_cube = np.abs(depth - cube_depth) < 0.05
    assert on_cube.sum() >= 6 and (alone.alpha[on_cube] > 0.5).any()
    assert np.abs(written[on_cube] - mesh_8[on_cube]).max() <= 1
    covered = (alone.alpha > 0.9) & (depth > 7.0)
    assert covered.sum() >= 6
    assert np.abs(written[covered][:, :3] - mesh_8[covered][:, :3]).max() > 20

    # The multilayer file: Blender's view layer (meshes), the composite, and the splat layer.
    composite = exr_layers.find_pass(channels, "Composite", "Combined", "RGBA")
    assert np.abs(composite - expected).max() < 2e-5
    splat_rgba = exr_layers.find_pass(channels, "Splats", "Combined", "RGBA")
    splat_depth = exr_layers.find_pass(channels, "Splats", "Depth", "Z")[..., 0]
    reference = premultiplied(np.concatenate([alone.rgb, alone.alpha[..., None]], -1), decode)
    assert np.abs(splat_rgba - reference).max() < 2e-5
    hit = np.isfinite(alone.depth)
    assert np.allclose(splat_depth[hit], alone.depth[hit], rtol=1e-6)
    assert (splat_depth[~hit] >= 1e9).all()


@pytest.mark.parametrize("engine", ENGINES)
def test_animation_with_a_moving_cube_and_camera(rng, tmp_path, engine):
    scene, splats, cube, plane, camera = build_scene(rng, engine)
    scene.frame_start, scene.frame_end = 1, 3
    for frame, x in ((1, -0.8), (3, 0.8)):
        cube.location.x = x
        cube.keyframe_insert("location", frame=frame)
        camera.location.x = 0.3 * x
        camera.keyframe_insert("location", frame=frame)
    settings = scene.render.image_settings
    settings.media_type, settings.file_format, settings.color_mode = "IMAGE", "PNG", "RGBA"
    scene.render.filepath = str(tmp_path / "anim_")
    assert bpy.ops.render.render(animation=True) == {"FINISHED"}
    settings.media_type = "MULTI_LAYER_IMAGE"
    settings.color_depth = "32"
    scene.render.filepath = str(tmp_path / "layers_")
    assert bpy.ops.render.render(animation=True) == {"FINISHED"}
    previous = None
    for frame in (1, 2, 3):
        scene.frame_set(frame)
        expected, *_ = expected_frame(scene, camera, tmp_path / f"layers_{frame:04d}.exr")
        written = read_png(tmp_path / f"anim_{frame:04d}.png")
        assert_close_8bit(written, standard_8bit(expected), f"{engine} frame {frame}")
        assert previous is None or np.abs(written - previous).max() > 20  # things moved
        previous = written


def test_renders_reuse_unchanged_splats_and_never_stale_ones(rng, tmp_path, monkeypatch):
    """A second F12, and the frames of an animation, reuse the transformed Gaussians of an
    unchanged splat object (each final render evaluates a new depsgraph); an object moved, or
    its data edited in place with no update at all (a script between two renders), is
    gathered again."""
    scene, splats, _, _, _ = build_scene(rng, "BLENDER_WORKBENCH")
    frames, read = [], []
    capture = hooks.capture_frame
    monkeypatch.setattr(hooks, "capture_frame",
                        lambda *args: frames.append(capture(*args)) or frames[-1])
    read_channels = exr_scanlines.read_channels
    monkeypatch.setattr(exr_scanlines, "read_channels",
                        lambda path, **options: read.append(path) or read_channels(path, **options))

    def rendered(name):
        render_still(scene, tmp_path / name)
        assert hooks.last_stats["gaussians"] == len(splats.data.vertices)
        assert "prepared_ms" in hooks.last_stats  # made while Blender wrote the EXR
        # the render's EXR copy (in /dev/shm: memory) is gone as soon as it is read
        assert read and not os.path.exists(read[-1])
        return frames[-1]

    g = splat_object.gaussians_from_data(splats.data)
    assert rendered("first").reused == 0
    again = rendered("again")
    assert again.reused == 1 and bs.gaussians_equal(again.gaussians, frames[0].gaussians)
    splats.location = (0.25, 0.0, 0.0)  # moved: transformed again
    moved = rendered("moved")
    assert moved.reused == 0 and np.allclose(moved.gaussians.means, g.means + (0.25, 0, 0))
    logits = np.linspace(-3, 3, len(g), dtype=np.float32)  # edited in place, no update()
    splats.data.attributes["opacity_logit"].data.foreach_set("value", logits)
    edited = rendered("edited")
    assert edited.reused == 0 and np.array_equal(edited.gaussians.opacity_logits, logits)
    assert rendered("unchanged").reused == 1
    # one bit of one SH value, in place: the checksum of the attribute where Blender keeps it
    name = splat_object.SH_NAMES[1]
    values = np.empty(3 * len(g), np.float32)
    splats.data.attributes[name].data.foreach_get("vector", values)
    values.view(np.uint32)[7] ^= 1
    splats.data.attributes[name].data.foreach_set("vector", values)
    bit = rendered("one bit")
    assert bit.reused == 0 and bit.gaussians.sh[2, 1, 1] == values[7]
    assert rendered("unchanged again").reused == 1
    frames.clear()
    scene.frame_start, scene.frame_end = 1, 3
    scene.render.filepath = str(tmp_path / "anim_")
    assert bpy.ops.render.render(animation=True) == {"FINISHED"}
    assert [f.reused for f in frames] == [1, 1, 1]
    assert all(np.array_equal(f.gaussians.opacity_logits, logits) for f in frames)
    frames.clear()  # animated: each frame where it moved is transformed again
    for frame, x in ((1, 0.25), (3, 0.75)):
        splats.location.x = x
        splats.keyframe_insert("location", frame=frame)
    assert bpy.ops.render.render(animation=True) == {"FINISHED"}
    assert [f.reused for f in frames] == [1, 0, 0]
    for f, x in zip(frames, (0.25, 0.5, 0.75)):
        assert np.allclose(f.gaussians.means, g.means + (x, 0, 0), atol=1e-6)


@pytest.mark.parametrize("transparent", [True, False])
def test_splat_only_pixels_are_the_reference_render(rng, tmp_path, transparent):
    """No meshes: the written PNG under "Standard" is the reference 3DGS render (straight
    colour and alpha over transparency; over the world colour, blended in display sRGB, with an
    opaque film)."""
    scene, splats, _, _, camera = build_scene(rng, "BLENDER_WORKBENCH", meshes=False)
    scene.render.film_transparent = transparent
    world = bpy.data.worlds.new("World")
    world.color = (0.2, 0.05, 0.1)
    scene.world = world
    written = read_png(render_still(scene, tmp_path / "splats"))
    depsgraph = bpy.context.evaluated_depsgraph_get()
    reference = render(bs.gather.gather(depsgraph).gaussians, bs.camera_of(camera, depsgraph))
    if transparent:
        alpha = reference.alpha
        straight = reference.rgb / np.where(alpha > 0, alpha, 1)[..., None]
        expected = np.concatenate([straight, alpha[..., None]], axis=-1)
        visible = alpha > 4 / 255  # the straight colour of fainter pixels is noise either way
        assert_close_8bit(written[..., 3], np.round(alpha * 255), "alpha")
        assert_close_8bit(written[visible][:, :3], np.round(np.clip(expected[visible][:, :3], 0, 1) * 255), "colour")
    else:
        # Workbench shows the world colour as it is (Blender's "viewport" world colour).
        background = encode(np.array(world.color[:3]))
        expected = reference.rgb + (1 - reference.alpha[..., None]) * background
        assert (written[..., 3] == 255).all()
        assert_close_8bit(written[..., :3], np.round(np.clip(expected, 0, 1) * 255), "colour")


def test_border_percentage_shift_and_pixel_aspect(rng, tmp_path):
    """A render border (cropped or not) gives exactly that part of the full composite; the
    camera's shift, the pixel aspect and the resolution percentage are Blender's."""
    scene, splats, cube, plane, camera = build_scene(rng, "BLENDER_WORKBENCH")
    scene.render.dither_intensity = 0.0  # two written files are compared: no dither noise
    scene.render.resolution_x, scene.render.resolution_y = 2 * WIDTH + 1, 2 * HEIGHT + 1
    scene.render.resolution_percentage = 50
    scene.render.pixel_aspect_x = 1.4
    camera.data.shift_x, camera.data.shift_y = 0.08, -0.05
    full = read_png(render_still(scene, tmp_path / "full"))
    expected, *_ = expected_frame(scene, camera, save_render_result(scene, tmp_path / "full.exr"))
    assert_close_8bit(full, standard_8bit(expected), "full frame")
    scene.render.use_border = True
    scene.render.border_min_x, scene.render.border_max_x = 0.2, 0.7
    scene.render.border_min_y, scene.render.border_max_y = 0.35, 0.9
    region = hooks.render_region(*camera_adapter.frame_size(scene.render),
                                        hooks.render_border(scene.render))
    scene.render.use_crop_to_border = True
    cropped = read_png(render_still(scene, tmp_path / "crop"))
    assert cropped.shape[:2] == (region.height, region.width)
    assert_close_8bit(cropped, full[region.slices()], "cropped border")
    scene.render.use_crop_to_border = False
    uncropped = read_png(render_still(scene, tmp_path / "border"))
    assert uncropped.shape == full.shape
    assert_close_8bit(uncropped[region.slices()], full[region.slices()], "border")
    outside = np.ones(full.shape[:2], bool)
    outside[region.slices()] = False
    assert (uncropped[outside] == 0).all()


def test_render_visibility_and_switches(rng, tmp_path):
    """Splats hidden from renders are not composed (the render's own depsgraph is read), and
    the scene switch turns the composite off; the file is then Blender's own render."""
    scene, splats, cube, plane, camera = build_scene(rng, "BLENDER_WORKBENCH")
    with_splats = read_png(render_still(scene, tmp_path / "a"))
    mesh_rgba, _, _ = mesh_layers(render_still(scene, tmp_path / "a", multilayer=True))
    meshes_only = standard_8bit(mesh_rgba)
    assert np.abs(with_splats - meshes_only).max() > 20
    splats.hide_render = True
    assert_close_8bit(read_png(render_still(scene, tmp_path / "b")), meshes_only, "hide_render")
    splats.hide_render = False
    scene.splat_render.enabled = False
    assert_close_8bit(read_png(render_still(scene, tmp_path / "c")), meshes_only, "switched off")


def reference_composite(gaussians, camera, mesh_rgba, mesh_depth, near):
    """The float64 reference (tests/reference.py) composed as `native_composite` is."""
    from tests import reference as ref
    out = ref.render_scene(gaussians, camera, near=near,
                           mesh_rgba=premultiplied(mesh_rgba, encode),
                           mesh_depth=np.where(np.isfinite(mesh_depth), mesh_depth, 1e10))
    return premultiplied(np.concatenate([out["rgb"], out["alpha"][..., None]], -1), decode)


def assert_close_to_reference(written, expected, what):
    """Within 1/255 at the median and 3/255 at the 99th percentile (8-bit rounding of both)."""
    diff = np.abs(written - standard_8bit(expected))
    assert np.median(diff) <= 1 and np.percentile(diff, 99) <= 3, \
        f"{what}: median {np.median(diff)}, 99th percentile {np.percentile(diff, 99)}/255"


@pytest.mark.parametrize("engine", ENGINES)
def test_orthographic_camera_is_the_exact_composite(rng, tmp_path, engine):
    scene, splats, cube, plane, camera = build_scene(rng, engine)
    camera.data.type = "ORTHO"
    camera.data.ortho_scale = 3.2
    camera.data.shift_x = 0.04
    written = read_png(render_still(scene, tmp_path / "ortho"))
    exr_path = render_still(scene, tmp_path / "layers", multilayer=True)
    mesh_rgba, mesh_depth, _ = mesh_layers(exr_path)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    gaussians = bs.gather.gather(depsgraph).gaussians
    cam = bs.camera_of(camera, depsgraph)
    assert cam.model == "ORTHO"
    near = max(scene.splat_render.near, camera.data.clip_start)
    expected = reference_composite(gaussians, cam, mesh_rgba, mesh_depth, near)
    assert_close_to_reference(written, expected, f"{engine} orthographic")
    # Meshes in front and behind: the cube hides the splats, the splats hide the plane.
    alone = render(gaussians, cam, near=near)
    on_cube = np.abs(mesh_depth - (6.0 - 2.5 - 0.45)) < 0.05
    assert on_cube.sum() >= 6 and (alone.alpha[on_cube] > 0.5).any()
    mesh_8 = standard_8bit(mesh_rgba)
    assert np.abs(written[on_cube] - mesh_8[on_cube]).max() <= 1
    covered = (alone.alpha > 0.9) & (mesh_depth > 7.0)
    assert covered.sum() >= 6
    assert np.abs(written[covered][:, :3] - mesh_8[covered][:, :3]).max() > 20


@pytest.mark.parametrize("kind", ["EQUIRECTANGULAR", "FISHEYE_EQUISOLID", "FISHEYE_EQUIDISTANT",
                                  "MIRRORBALL", "FISHEYE_LENS_POLYNOMIAL",
                                  "EQUIANGULAR_CUBEMAP_FACE", "CENTRAL_CYLINDRICAL"])
def test_panoramic_camera_is_the_composite(rng, tmp_path, kind):
    scene, splats, cube, plane, camera = build_scene(rng, "CYCLES")
    scene.render.resolution_x, scene.render.resolution_y = 64, 32
    camera.data.type = "PANO"
    pano = camera.data if hasattr(camera.data, "panorama_type") else camera.data.cycles
    pano.panorama_type = kind
    pano.fisheye_fov = math.radians(160)
    pano.fisheye_lens = 6.0
    if kind == "CENTRAL_CYLINDRICAL":  # 200 degrees around, heights -0.5..1.5 on a radius-2 one
        pano.central_cylindrical_range_u_min = math.radians(-90)
        pano.central_cylindrical_range_u_max = math.radians(110)
        pano.central_cylindrical_range_v_min, pano.central_cylindrical_range_v_max = -0.5, 1.5
        pano.central_cylindrical_radius = 2.0
    camera.data.shift_x, camera.data.shift_y = 0.06, -0.04  # moves the viewplane (Cycles)
    written = read_png(render_still(scene, tmp_path / "pano"))
    exr_path = render_still(scene, tmp_path / "layers", multilayer=True)
    mesh_rgba, mesh_depth, _ = mesh_layers(exr_path)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    gaussians = bs.gather.gather(depsgraph).gaussians
    cam = bs.camera_of(camera, depsgraph)
    assert cam.model == kind
    near = max(scene.splat_render.near, camera.data.clip_start)
    expected = native_composite(gaussians, cam, mesh_rgba, mesh_depth)
    alone = render(gaussians, cam, near=near)
    assert alone.alpha.max() > 0.5  # the splats are in the frame
    # Cycles' depth for panoramas is the distance, which the splats are composed by: the cube
    # (its nearest face 3.05 away, straight ahead) hides them where it is.
    on_cube = (mesh_depth < 3.6) & (mesh_rgba[..., 3] > 0.99)
    assert on_cube.sum() >= 4 and (alone.alpha[on_cube] > 0.5).any()
    # Where Cycles drew the cube is where the camera model puts it, not mirrored: a point near
    # the cube's upper right corner, whose mirror images (left-right, up-down) are off it.
    from addon.core.gaussians import Gaussians
    from addon.core.render.renderer import project
    # (mirrored about the image of the view axis, which the shift moves)
    probe = Gaussians(np.float32([[0.65, -2.96, 0.45], [0.0, -2.96, 0.0]]),
                      np.full((2, 3), -5, np.float32), np.float32([[1, 0, 0, 0]] * 2),
                      np.float32([5, 5]), np.zeros((2, 1, 3), np.float32))
    (x, y), (x0, y0) = project(probe, cam).xy
    col, row = int(x), int(y)
    assert mesh_depth[row, col] < 3.6
    assert mesh_depth[row, int(2 * x0 - x)] > 3.6
    assert mesh_depth[int(2 * y0 - y), col] > 3.6
    mesh_8 = standard_8bit(mesh_rgba)
    assert np.abs(written[on_cube] - mesh_8[on_cube]).max() <= 1
    if kind not in ("EQUIRECTANGULAR", "EQUIANGULAR_CUBEMAP_FACE", "CENTRAL_CYLINDRICAL"):
        # outside the image circle: no splats, whatever is there
        from addon.core.cameras import image_coverage
        outside = ~image_coverage(cam)
        assert outside.sum() > 10 or kind == "FISHEYE_LENS_POLYNOMIAL"  # (its circle: 160 deg)
        assert not outside.any() or np.abs(written[outside] - mesh_8[outside]).max() <= 1
        expected[outside] = mesh_rgba[outside]
    assert_close_8bit(written, standard_8bit(expected), kind)


def test_depth_of_field_blurs_the_splats(rng, tmp_path):
    import dataclasses
    scene, splats, cube, plane, camera = build_scene(rng, "BLENDER_WORKBENCH")
    camera.data.dof.use_dof = True
    camera.data.dof.aperture_fstop = 0.1  # circles of confusion of 1-2 pixels at 32x24
    camera.data.dof.focus_distance = 2.0
    written = read_png(render_still(scene, tmp_path / "dof"))
    exr_path = render_still(scene, tmp_path / "layers", multilayer=True)
    expected, mesh_rgba, channels, gaussians, cam = expected_frame(scene, camera, exr_path)
    assert cam.aperture == pytest.approx(0.035 / 0.2) and cam.focus == pytest.approx(2.0)
    assert_close_8bit(written, standard_8bit(expected), "depth of field")
    _, mesh_depth, _ = mesh_layers(exr_path)
    sharp = native_composite(gaussians, dataclasses.replace(cam, aperture=0.0), mesh_rgba,
                             mesh_depth)
    # The blur shows: summed over the frame, the written image is far nearer the blurred
    # expectation (0-1 levels in all here) than the sharp render (1,500-2,800 levels; its
    # largest single difference is as small as 10 levels in some random scenes).
    to_sharp = np.abs(written - standard_8bit(sharp)).sum()
    to_blurred = np.abs(written - standard_8bit(expected)).sum()
    assert to_sharp > 20 * (to_blurred + 10), (to_sharp, to_blurred)


def test_depth_of_field_through_a_panorama_fails(rng, tmp_path):
    scene, splats, cube, plane, camera = build_scene(rng, "CYCLES")
    camera.data.type = "PANO"
    camera.data.dof.use_dof = True
    _render_fails_with(scene, tmp_path, "depth of field")


def test_panoramic_camera_without_cycles_fails(rng, tmp_path):
    scene, splats, cube, plane, camera = build_scene(rng, "BLENDER_WORKBENCH")
    camera.data.type = "PANO"
    _render_fails_with(scene, tmp_path, "render it with Cycles")


def test_unsupported_cameras_fail_the_render(rng, tmp_path):
    # Every panorama type renders; custom (OSL) cameras (Blender 5.0 on) do not.
    scene, splats, cube, plane, camera = build_scene(rng, "CYCLES")
    if "CUSTOM" not in {e.identifier for e in
                        bpy.types.Camera.bl_rna.properties["type"].enum_items}:
        pytest.skip("this Blender has no custom cameras")
    camera.data.type = "CUSTOM"
    _render_fails_with(scene, tmp_path, "custom camera")


def _render_fails_with(scene, tmp_path, match):
    from addon.blender.render import failures
    scene.render.filepath = str(tmp_path / "failed")
    settings = scene.render.image_settings
    settings.media_type, settings.file_format = "IMAGE", "PNG"
    try:
        result = bpy.ops.render.render(write_still=True)
    except RuntimeError:
        result = {"CANCELLED"}
    assert result == {"CANCELLED"} or not list(tmp_path.glob("failed*"))
    assert not list(tmp_path.glob("failed*"))
    assert any(match in e for e in failures.last_errors()), failures.last_errors()


@pytest.mark.parametrize("composite", [True, False], ids=["splats", "composite-off"])
def test_render_cache_path_gives_the_same_image(rng, tmp_path, composite):
    """Where the render is read from Blender's render cache file (the UI; a command-line render
    of a file with no "Render Result" image) rather than saved from the Render Result: the same
    image, also where "Composite Splats" is off and the helper passes the meshes through."""
    scene, *_ = build_scene(rng, "BLENDER_WORKBENCH")
    render_still(scene, tmp_path / "first")  # the bridge is set up: it stays when turned off
    scene.splat_render.enabled = composite
    normal = read_png(render_still(scene, tmp_path / "normal"))
    assert "save_ms" in hooks.last_stats
    state.current.force_cache_file = True
    try:
        cached = read_png(render_still(scene, tmp_path / "cached"))
    finally:
        state.current.force_cache_file = False
    assert "save_ms" not in hooks.last_stats and "read_ms" in hooks.last_stats
    assert not scene.render.use_render_cache  # put back after the render
    assert np.array_equal(cached, normal)


def test_render_splats_only_engine(rng, tmp_path, capfd):
    scene, splats, cube, plane, camera = build_scene(rng, "BLENDER_WORKBENCH")
    scene.render.film_transparent = True
    bpy.ops.splat.render_splats_only(enable=True)
    assert scene.render.engine == compositor_bridge.ENGINE_ID
    capfd.readouterr()
    written = read_png(render_still(scene, tmp_path / "quick"))
    depsgraph = bpy.context.evaluated_depsgraph_get()
    gaussians = bs.gather.gather(depsgraph).gaussians
    reference = render(gaussians, bs.camera_of(camera, depsgraph))
    assert_close_8bit(written[..., 3], np.round(reference.alpha * 255), "alpha")
    # The log counts the splats rendered (the bridge's pass-through of them counts none).
    logged = [line for line in capfd.readouterr().out.splitlines()
              if line.startswith("Gaussian splats: ")]
    assert logged and all(f"{len(gaussians):,} splats" in line for line in logged), logged
    bpy.ops.splat.render_splats_only(enable=False)
    assert scene.render.engine == "BLENDER_WORKBENCH"


def test_bridge_keeps_and_restores_a_users_compositor(rng):
    scene, *_ = build_scene(rng, "BLENDER_WORKBENCH")
    hooks.set_up_bridge_later(scene.name)  # what the UI does once splats appear in a scene
    assert compositor_bridge.bridge_node(scene) is not None
    assert compositor_bridge.remove_bridge(scene)
    assert scene.compositing_node_group is None
    tree = bpy.data.node_groups.new("Mine", "CompositorNodeTree")
    scene.compositing_node_group = tree
    layers = tree.nodes.new("CompositorNodeRLayers")
    layers.scene = scene
    blur = tree.nodes.new("CompositorNodeBlur")
    output = tree.nodes.new("NodeGroupOutput")
    tree.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
    tree.links.new(layers.outputs["Image"], blur.inputs[0])
    tree.links.new(blur.outputs[0], output.inputs[0])
    assert compositor_bridge.ensure_bridge(scene)
    assert not compositor_bridge.ensure_bridge(scene)  # idempotent
    node = compositor_bridge.bridge_node(scene)
    assert blur.inputs[0].links[0].from_node == node
    assert compositor_bridge.problems(scene) == []
    assert compositor_bridge.remove_bridge(scene)
    assert blur.inputs[0].links[0].from_node == layers
    assert scene.compositing_node_group == tree and len(tree.nodes) == 3
    assert compositor_bridge.helper_scene(create=False) is None


def test_splats_a_job_adds_are_bridged_in_their_own_update(rng):
    """The UI makes the F12 helper scene ahead (`make_helper_ahead`: at a COLMAP import, or at
    the click that starts a job) and bridges a scene in the same update as a job's first splats
    (`bridge_new_splats`), not from a timer after it: each is a run of redraws (issue 36)."""
    scene, splats, *_ = build_scene(rng, "BLENDER_WORKBENCH")
    gaussians = bs.mesh_gaussians(splats)
    bpy.data.objects.remove(splats)
    assert compositor_bridge.helper_scene(create=False) is None
    scene.render.engine = compositor_bridge.ENGINE_ID
    hooks.make_helper_ahead(scene)
    assert compositor_bridge.helper_scene(create=False) is None  # the splats-only engine
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.splat_render.enabled = False
    hooks.make_helper_ahead(scene)
    assert compositor_bridge.helper_scene(create=False) is None  # Composite Splats off
    scene.splat_render.enabled = True
    hooks.make_helper_ahead(scene)
    assert compositor_bridge.helper_scene(create=False) is not None
    assert compositor_bridge.bridge_node(scene) is None  # no splats yet: nothing to bridge
    hooks.bridge_new_splats(None)  # a job that wrote nothing
    gone = splat_object.create_splat_object(gaussians, "Removed")
    bpy.data.objects.remove(gone)
    hooks.bridge_new_splats(gone)  # its object removed meanwhile
    assert compositor_bridge.bridge_node(scene) is None
    obj = splat_object.create_splat_object(gaussians, "Trained")
    hooks.bridge_new_splats(obj)
    assert compositor_bridge.bridge_node(scene) is not None
    assert compositor_bridge.problems(scene) == []


def test_a_compositor_reading_the_depth_gets_the_composites(rng, tmp_path):
    """The helper render fills its Depth pass only when the compositor reads it (the bridge
    node's Depth output linked, e.g. by a user's compositor): then that is the composite's."""
    scene, _, _, _, camera = build_scene(rng, "BLENDER_WORKBENCH")
    hooks.set_up_bridge_later(scene.name)
    assert not compositor_bridge.uses_depth(scene)
    tree = scene.compositing_node_group
    output = next(n for n in tree.nodes if n.bl_idname == "NodeGroupOutput")
    tree.links.new(compositor_bridge.bridge_node(scene).outputs["Depth"], output.inputs[0])
    assert compositor_bridge.uses_depth(scene)
    settings = scene.render.image_settings
    settings.media_type, settings.file_format = "IMAGE", "OPEN_EXR"
    settings.color_depth, settings.exr_codec = "32", "NONE"
    scene.render.filepath = str(tmp_path / "depth")
    assert bpy.ops.render.render(write_still=True) == {"FINISHED"}
    written = exr_layers.read_channels(tmp_path / "depth.exr")["R"]
    mesh_rgba, mesh_depth, _ = mesh_layers(render_still(scene, tmp_path / "layers",
                                                        multilayer=True))
    depsgraph = bpy.context.evaluated_depsgraph_get()
    expected = compose(bs.gather.gather(depsgraph).gaussians, bs.camera_of(camera, depsgraph),
                       mesh_rgba, mesh_depth).depth
    assert (np.abs(expected - mesh_depth) > 0.01).sum() > 20  # the splats are in it
    assert np.allclose(written, expected, rtol=1e-6)


class _Layout:
    """Records what a panel draws (headless Blender has no UI to draw into)."""

    def __init__(self, log):
        self.log, self.use_property_split, self.use_property_decorate = log, False, False
        self.active = True

    def _child(self, *args, **kwargs):
        return _Layout(self.log)

    row = column = box = _child

    def prop(self, data, name, **kwargs):
        assert hasattr(data, name), name
        self.log.append(("prop", name))

    def label(self, text="", **kwargs):
        self.log.append(("label", text))

    def operator(self, idname, **kwargs):
        module, name = idname.split(".")
        assert hasattr(getattr(bpy.ops, module), name), idname
        self.log.append(("operator", idname))
        return type("Props", (), {})()


def test_render_panel_draws(rng, tmp_path):
    scene, *_ = build_scene(rng, "BLENDER_WORKBENCH")
    panel = bpy.types.RENDER_PT_splats
    context = type("Context", (), {"scene": scene})()
    for step in ("no bridge", "bridged", "rendered", "splats only"):
        if step == "bridged":
            compositor_bridge.ensure_bridge(scene)
        elif step == "rendered":
            render_still(scene, tmp_path / "panel")
        elif step == "splats only":
            bpy.ops.splat.render_splats_only(enable=True)
        log = []
        fake = type("Panel", (), {"layout": _Layout(log)})()
        panel.draw(fake, context)
        names = {entry[1] for entry in log}
        assert {"antialiased", "sh_degree", "near", "threads", "viewport"} <= names, step
        assert "splat.render_splats_only" in names
    obj_panel = bpy.types.OBJECT_PT_splat
    log = []
    obj_panel.draw(type("Panel", (), {"layout": _Layout(log)})(),
                   type("Context", (), {"object": bpy.data.objects["Splats"]})())
    assert ("prop", "show_in_viewport") in log
