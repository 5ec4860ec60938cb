"""Splats composed with a mesh layer in Blender's colour conventions (no bpy):
`addon.core.colour` and `addon.core.composite`."""

from __future__ import annotations

import numpy as np
import pytest

from addon.core import colour
from addon.core.composite import FAR, compose, embed, render_region, splat_layer
from addon.core.render import render
from scenes import random_mesh_layer, random_scene


def test_srgb_transfer_matches_the_standard_and_inverts():
    linear = np.array([0.0, 0.0031308, 0.01, 0.18, 0.5, 1.0])
    # IEC 61966-2-1 values
    expected = np.array([0.0, 0.04044994, 0.09985282, 0.46135613, 0.73535698, 1.0])
    assert np.allclose(colour.srgb_encode(linear), expected, atol=1e-7)
    x = np.concatenate([np.linspace(-2, 8, 20001), [1e-8, -1e-8]])
    assert np.allclose(colour.srgb_decode(colour.srgb_encode(x)), x, rtol=1e-12, atol=1e-15)
    assert colour.srgb_encode(x.astype(np.float32)).dtype == np.float32
    assert np.all(np.diff(colour.srgb_encode(np.linspace(-2, 8, 20001))) > 0)  # monotonic


def test_premultiplied_conversion_goes_through_the_straight_colour(rng):
    rgba = rng.random((50, 4)).astype(np.float32)
    rgba[:, :3] *= rgba[:, 3:]
    display = colour.display_from_linear(rgba)
    straight = rgba[:, :3] / rgba[:, 3:]
    assert np.allclose(display[:, :3], colour.srgb_encode(straight) * rgba[:, 3:], atol=1e-6)
    assert np.array_equal(display[:, 3], rgba[:, 3])
    assert np.allclose(colour.linear_from_display(display), rgba, atol=2e-6)
    # zero alpha with colour (additive light) converts as if opaque, and still inverts
    glow = np.array([[0.2, 0.1, 0.0, 0.0]], np.float32)
    assert np.allclose(colour.display_from_linear(glow)[0, :3], colour.srgb_encode(glow[0, :3]))
    assert np.allclose(colour.linear_from_display(colour.display_from_linear(glow)), glow)


def test_compose_is_the_native_composite_in_display_space(rng):
    gaussians, camera = random_scene(rng, 60, 40, 30, 2)
    mesh_rgba, mesh_depth = random_mesh_layer(rng, 40, 30)
    mesh_depth = np.where(np.isfinite(mesh_depth), mesh_depth, FAR).astype(np.float32)
    result = compose(gaussians, camera, mesh_rgba, mesh_depth)
    native = render(gaussians, camera, mesh_rgba=colour.display_from_linear(mesh_rgba),
                    mesh_depth=mesh_depth)
    expected = colour.linear_from_display(np.concatenate([native.rgb, native.alpha[..., None]], -1))
    assert np.allclose(result.rgba, expected, atol=1e-6)
    # pixels no splat reaches keep the mesh layer bit for bit (a few splats, so that such
    # pixels exist whatever the seed: 60 random ones can cover the whole image)
    few = gaussians.subset(np.arange(len(gaussians)) < 3)
    alone = render(few, camera)
    untouched = alone.alpha == 0
    assert untouched.sum() > 20
    assert np.array_equal(compose(few, camera, mesh_rgba, mesh_depth).rgba[untouched],
                          mesh_rgba[untouched])
    # linear splats compose with the linear layer as is
    linear = compose(gaussians, camera, mesh_rgba, mesh_depth, color_space="LINEAR")
    native = render(gaussians, camera, mesh_rgba=mesh_rgba, mesh_depth=mesh_depth)
    assert np.array_equal(linear.rgba[..., :3], native.rgb)
    with pytest.raises(ValueError, match="color_space"):
        compose(gaussians, camera, mesh_rgba, mesh_depth, color_space="ACES")
    with pytest.raises(ValueError, match="mesh_rgba"):
        compose(gaussians, camera, mesh_rgba[1:], mesh_depth)


def test_splat_layer_over_a_background_is_the_reference_blend(rng):
    gaussians, camera = random_scene(rng, 200, 32, 24, 1)
    background = np.array([0.2, 0.05, 0.5], np.float32)
    layer = splat_layer(gaussians, camera, background=background)
    reference = render(gaussians, camera)
    display = reference.rgb + (1 - reference.alpha[..., None]) * colour.srgb_encode(background)
    assert np.allclose(colour.srgb_encode(layer.rgba[..., :3]), display, atol=2e-6)
    assert (layer.rgba[..., 3] == 1).all()
    bare = splat_layer(gaussians, camera)
    assert np.array_equal(bare.rgba[..., 3], reference.alpha)
    assert (bare.depth[reference.alpha == 0] == FAR).all()


def test_render_region_and_embed():
    region = render_region(61, 45, (0.2, 0.7, 0.35, 0.9))  # int(0.2*61) = 12, int(0.7*61) = 42
    assert (region.x, region.width) == (12, 30) and (region.y, region.height) == (45 - 40, 40 - 15)
    assert render_region(61, 45, None).slices() == (slice(0, 45), slice(0, 61))
    rgba = np.ones((region.height, region.width, 4), np.float32)
    full_rgba, full_depth = embed(rgba, np.ones(rgba.shape[:2], np.float32), region, 61, 45)
    assert full_rgba.sum() == rgba.sum() and (full_rgba[region.slices()] == 1).all()
    assert (full_depth == FAR).sum() == 61 * 45 - region.width * region.height
