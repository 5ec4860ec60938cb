"""A mesh standing on a captured (splat) floor casts its shadow onto it in the final render
(bpy, Cycles): the floor's proxy (`mesh_convert.make_proxy`, a shadow catcher) catches the
shadow and the compositor bridge multiplies it over the composite (docs/guide/meshes.md).

The scene: a flat opaque layer of yellow Gaussians at z = 0 (4 x 4 units), its proxy (a plane
made a proxy by hand, or the floor converted with `proxy=True`), a 0.6 cube standing on it, a
sun lighting it from +x at 55 degrees (the shadow falls towards -x), a camera looking down at
55 degrees; 48x36 pixels, Cycles CPU at 8 samples, rendered with `bpy.ops.render.render`.
"""

from __future__ import annotations

import math

import bpy_support as bs
from bpy_support import bpy  # the shared bpy import
import numpy as np
import pytest

from addon.blender.render import compositor_bridge
from addon.blender import mesh_convert, splat_object
from addon.blender.sources import gather
from addon.core.images import exr_layers
from addon.core.render.composite import apply_shadow_catcher
from addon.core.gaussians import Gaussians

WIDTH, HEIGHT = 48, 36
FLOOR_R = 0.8  # the floor Gaussians' colour (0.8, 0.7, 0.3), display sRGB


def floor_gaussians(n: int = 24, half: float = 2.0) -> Gaussians:
    xs = np.linspace(-half, half, n)
    x, y = np.meshgrid(xs, xs)
    means = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    step = 2 * half / (n - 1)
    count = len(means)
    colour = (np.array([FLOOR_R, 0.7, 0.3]) - 0.5) / 0.28209479
    return Gaussians(means, np.tile(np.log([0.7 * step, 0.7 * step, 0.002]), (count, 1)),
                     np.tile([1.0, 0, 0, 0], (count, 1)), np.full(count, 6.0),
                     np.tile(colour[None, None, :], (count, 1, 1)))


def build(*, transparent: bool, cube: bool, converted: bool = False):
    bs.reset_scene()
    scene = bpy.context.scene
    floor = splat_object.create_splat_object(floor_gaussians(), "Floor")
    if converted:
        proxy = mesh_convert.convert_to_mesh(floor, resolution=64, max_triangles=2000,
                                             texture_size=32, cameras="SPHERE", proxy=True,
                                             view_count=16, view_size=64)
    else:
        bpy.ops.mesh.primitive_plane_add(size=4.0, location=(0, 0, 0))
        proxy = bpy.context.active_object
        mesh_convert.make_proxy(proxy, floor)
    if cube:
        bpy.ops.mesh.primitive_cube_add(size=0.6, location=(0, 0, 0.3))
        mat = bpy.data.materials.new("Cube")
        bsdf = next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
        bsdf.inputs["Base Color"].default_value = (0.1, 0.3, 0.9, 1)
        bpy.context.active_object.data.materials.append(mat)
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    sun.data.energy, sun.data.angle = 3.0, 0.0
    sun.rotation_euler = (0, math.radians(55), 0)
    scene.collection.objects.link(sun)
    bs.add_camera(location=(0, -5.0, 3.5), rotation=(math.radians(55), 0, 0), lens=35,
                  width=WIDTH, height=HEIGHT)
    scene.world = bpy.data.worlds.new("World")
    scene.world.color = (0.05, 0.05, 0.05)
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 8
    scene.cycles.seed = 0
    scene.cycles.use_denoising = False
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.max_bounces = 1
    scene.render.film_transparent = transparent
    scene.render.threads_mode = "FIXED"
    scene.render.threads = 2
    scene.view_settings.view_transform = "Standard"
    return scene, proxy


def render_layers(scene, path) -> dict:
    settings = scene.render.image_settings
    settings.media_type = "MULTI_LAYER_IMAGE"
    settings.color_depth = "32"
    scene.render.filepath = str(path)
    assert bpy.ops.render.render(write_still=True) == {"FINISHED"}
    channels = exr_layers.read_channels(f"{path}.exr")
    return {"composite": exr_layers.find_pass(channels, "Composite", "Combined", "RGBA"),
            "mesh": exr_layers.find_pass(channels, "ViewLayer", "Combined", "RGBA"),
            "shadow": exr_layers.find_pass(channels, "ViewLayer", "Shadow Catcher", "RGB"),
            "splats": exr_layers.find_pass(channels, "Splats", "Combined", "RGBA")}


@pytest.fixture(autouse=True)
def clean():
    yield
    gather.clear_cache()


@pytest.mark.parametrize("transparent, converted",
                         [(True, False), (False, False), (True, True)],
                         ids=["transparent", "opaque-film", "converted-proxy"])
def test_cube_casts_its_shadow_onto_the_splat_floor(tmp_path, transparent, converted):
    scene, proxy = build(transparent=transparent, cube=True, converted=converted)
    lit = render_layers(scene, tmp_path / "cube")
    assert lit["shadow"] is not None, "the bridge must turn on Cycles' Shadow Catcher pass"
    assert scene.view_layers[0].cycles.use_pass_shadow_catcher
    assert compositor_bridge.problems(scene) == []
    scene, _ = build(transparent=transparent, cube=False, converted=converted)
    bare = render_layers(scene, tmp_path / "bare")

    comp, bare_comp = lit["composite"], bare["composite"]
    # The cube covers these pixels (wholly or in part): the mesh layer differs there.
    cube = np.abs(lit["mesh"] - bare["mesh"]).max(axis=-1) > 1e-3
    inner = cube.copy()  # wholly: the neighbours are cube pixels too
    inner[1:-1, 1:-1] &= cube[:-2, 1:-1] & cube[2:, 1:-1] & cube[1:-1, :-2] & cube[1:-1, 2:]
    inner[[0, -1], :] = inner[:, [0, -1]] = False
    in_shadow = (lit["shadow"].mean(axis=-1) < 0.3) & ~cube
    floor = (lit["splats"][..., 3] > 0.99) & ~cube      # the splat floor covers these
    lit_floor = floor & ~in_shadow & (lit["shadow"].min(axis=-1) > 0.95)
    assert in_shadow.sum() >= 8 and lit_floor.sum() > 300
    assert (in_shadow & floor).sum() >= 8

    shade = comp[in_shadow & floor, 0].mean()
    sunny = comp[lit_floor, 0].mean()
    without_cube = bare_comp[in_shadow & floor, 0].mean()
    # The shadow is clearly there: the splat floor is dark where the cube's shadow falls...
    assert shade < 0.35 * sunny, (shade, sunny)
    assert shade < 0.35 * without_cube, (shade, without_cube)
    # ... and nowhere else: the floor outside the shadow is the splats, as without the cube
    # (the proxy's own surface never shows, with transparent film or not).
    for other in (bare_comp, lit["splats"]):
        diff = np.abs(comp[lit_floor] - other[lit_floor])
        assert diff.max() < 0.08 and diff.mean() < 0.005, (diff.max(), diff.mean())
    assert sunny > 0.55  # display sRGB 0.8 -> about 0.6 scene-linear
    # The cube stands in front of the floor: its pixels are Blender's.
    # (Blue, Blender's own pixels; the yellow floor does not show through.)
    assert inner.sum() >= 4
    assert (comp[inner, 2] > comp[inner, 0]).mean() > 0.75
    assert np.median(np.abs(comp[inner] - lit["mesh"][inner])) < 1e-5
    # Background: the world (opaque film) or transparency, as Blender rendered it.
    empty = (lit["splats"][..., 3] < 1e-3) & (lit["shadow"].min(axis=-1) > 0.999) & ~cube
    assert empty.sum() > 100
    assert np.allclose(comp[empty], lit["mesh"][empty], atol=1e-5)


def test_apply_shadow_catcher():
    rgba = np.array([[[0.5, 0.4, 0.2, 1.0], [0.0, 0.0, 0.0, 0.0], [0.3, 0.3, 0.3, 0.5]]],
                    np.float32)
    shadow = np.array([[[0.25, 0.25, 0.25], [0.5, 0.5, 0.5], [1.0, 1.0, 1.0]]], np.float32)
    out = apply_shadow_catcher(rgba, shadow)
    assert np.allclose(out[0, 0], [0.125, 0.1, 0.05, 1.0])
    assert np.allclose(out[0, 1], [0.0, 0.0, 0.0, 0.5])    # shadow over transparency
    assert np.array_equal(out[0, 2], rgba[0, 2])             # no shadow: unchanged
    # A catcher only darkens: factors above 1 (light the catcher picked up) are ignored.
    assert np.array_equal(apply_shadow_catcher(rgba, shadow * 4), rgba)


def test_only_geometry_catches_shadows(rng):
    """Blender reports lights as shadow catchers; the bridge turns the Shadow Catcher pass on
    for a real catcher only (the pass costs Cycles work and a larger render to read)."""
    bs.reset_scene()
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    splat_object.create_splat_object(Gaussians.empty(), "Splats")
    light = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    scene.collection.objects.link(light)
    layer = scene.view_layers[0]
    layer.cycles.use_pass_shadow_catcher = False
    compositor_bridge.ensure_bridge(scene)
    assert not compositor_bridge.has_shadow_catchers(scene)
    assert not layer.cycles.use_pass_shadow_catcher
    bpy.ops.mesh.primitive_plane_add()
    bpy.context.active_object.is_shadow_catcher = True
    assert compositor_bridge.needs_shadow_pass(scene, layer)
    compositor_bridge.ensure_bridge(scene)
    assert layer.cycles.use_pass_shadow_catcher
