"""Splats composed with a mesh layer in Blender's colour conventions (no bpy):
`addon.core.colour` and `addon.core.render.composite`."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from addon.core import colour, native
from addon.core.render.composite import FAR, compose, embed, prepare, render_region, splat_layer
from addon.core.render.renderer import render
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


def _srgb64(x: np.ndarray, encode: bool) -> np.ndarray:
    """The sRGB transfer in float64, written out here (independent of addon.core.colour)."""
    a = np.abs(x.astype(np.float64))
    if encode:
        y = np.where(a <= 0.0031308, 12.92 * a, 1.055 * np.maximum(a, 0.0031308) ** (1 / 2.4) - 0.055)
    else:
        y = np.where(a <= 0.04045, a / 12.92, ((np.maximum(a, 0.04045) + 0.055) / 1.055) ** 2.4)
    return np.where(x < 0, -y, y)


@pytest.mark.parametrize("encode", [True, False])
def test_conversions_of_large_images_block_by_block_and_in_place(rng, encode):
    """Images much larger than a conversion block, mixing opaque and transparent stretches,
    negative, tiny and non-finite values, match the float64 transfer; converting into the
    input array itself (`out=`) gives the same bits."""
    rgba = (rng.random((300, 700, 4)) * 1.5).astype(np.float32)
    rgba[:100, :, 3] = 1.0                                   # opaque blocks
    rgba[100:, :, 3] = rng.random((200, 700)).astype(np.float32)
    rgba[150:160, :, 3] = 0.0                                # colour with zero alpha
    rgba[200:205] *= 1e-4                                    # the linear segment
    rgba[210, :, :3] *= -1                                   # negative colour
    rgba[220, 5, 1], rgba[221, 6, 0], rgba[222, 7, 2] = np.nan, np.inf, -0.0
    rgba[:, :, :3] *= np.where(rgba[:, :, 3:] > 0, rgba[:, :, 3:], 1)  # premultiplied
    convert = colour.display_from_linear if encode else colour.linear_from_display
    result = convert(rgba)
    alpha = rgba[..., 3:].astype(np.float64)
    scale = np.where(alpha > 0, alpha, 1.0)
    expected = _srgb64(rgba[..., :3] / scale, encode) * scale
    finite = np.isfinite(expected)
    assert np.array_equal(np.isfinite(result[..., :3]), finite)
    assert np.allclose(result[..., :3][finite], expected[finite], rtol=2e-6, atol=1e-7)
    assert np.array_equal(result[..., 3], rgba[..., 3])
    again = rgba.copy()
    assert convert(again, out=again) is again
    assert np.array_equal(again.view(np.uint32), result.view(np.uint32))
    flat = rgba.reshape(-1)[:100_003]
    plain = (colour.srgb_encode if encode else colour.srgb_decode)(flat)
    assert np.allclose(plain[np.isfinite(plain)], _srgb64(flat, encode)[np.isfinite(plain)],
                       rtol=2e-6, atol=1e-7)
    with pytest.raises(ValueError, match="out must be"):
        convert(rgba, out=np.empty((300, 700, 4), np.float64))


@pytest.mark.parametrize("convert", [colour.display_from_linear, colour.linear_from_display])
def test_runs_of_one_colour_convert_as_each_pixel_does(rng, convert):
    """A background of one colour (converted once per run of identical pixels) with scattered
    other pixels, opaque and not: every pixel is what converting it alone gives, bit for bit."""
    image = np.empty((300, 500, 4), np.float32)
    image[...] = (0.05, 0.06, 0.08, 1.0)
    image[150:, :, :] = (0.02, 0.0, 0.3, 0.5)                     # a transparent stretch
    spots = rng.integers(0, 300 * 500, 400)
    image.reshape(-1, 4)[spots] = rng.random((400, 4)).astype(np.float32)
    result = convert(image).reshape(-1, 4)
    for index in np.concatenate([spots[:50], [0, 1, 74_999, 75_000, 149_999]]):
        alone = convert(image.reshape(-1, 4)[index:index + 1])
        assert np.array_equal(result[index].view(np.uint32), alone[0].view(np.uint32))


def test_compose_of_a_large_image_is_the_same_on_any_thread_count(rng):
    """Many conversion blocks, on one thread or several: the same bits, and the composite."""
    # A scene that leaves some pixels to the meshes alone (300 random Gaussians now and then
    # cover the whole frame: seed 1225153239).
    for _ in range(20):
        gaussians, camera = random_scene(rng, 300, 320, 240, 1)
        untouched = render(gaussians, camera, threads=1).alpha == 0
        if untouched.any() and (~untouched).any():
            break
    else:
        pytest.fail("no random scene with both splat and mesh-only pixels in 20 draws")
    mesh_rgba, mesh_depth = random_mesh_layer(rng, 320, 240)
    one = compose(gaussians, camera, mesh_rgba, mesh_depth, threads=1)
    many = compose(gaussians, camera, mesh_rgba, mesh_depth, threads=3)
    assert np.array_equal(one.rgba.view(np.uint32), many.rgba.view(np.uint32))
    assert np.array_equal(one.depth, many.depth)
    native = render(gaussians, camera, mesh_rgba=colour.display_from_linear(mesh_rgba),
                    mesh_depth=np.where(np.isfinite(mesh_depth), mesh_depth, FAR), threads=1)
    composite = np.concatenate([native.rgb, native.alpha[..., None]], -1).astype(np.float64)
    alpha = composite[..., 3:]
    scale = np.where(alpha > 0, alpha, 1.0)
    expected = _srgb64(composite[..., :3] / scale, False) * scale
    assert np.allclose(one.rgba[..., :3], expected, atol=2e-6)
    assert np.array_equal(one.rgba[untouched], mesh_rgba[untouched])


def test_compose_reads_strided_layers_and_writes_where_asked(rng):
    """A mesh layer given as a read-only strided view (as F12 reads it from the EXR's planar
    channels) and an `out` with reversed rows (a render pass's order) give the same bits."""
    gaussians, camera = random_scene(rng, 80, 64, 48, 1)
    mesh_rgba, mesh_depth = random_mesh_layer(rng, 64, 48)
    mesh_rgba[..., 0][::5] = np.nan
    expected = compose(gaussians, camera, mesh_rgba, mesh_depth)
    planar = np.ascontiguousarray(mesh_rgba.transpose(0, 2, 1))
    view = np.lib.stride_tricks.as_strided(planar, mesh_rgba.shape,
                                           (planar.strides[0], 4, planar.strides[1]),
                                           writeable=False)
    for space in ("SRGB", "LINEAR"):
        want = expected if space == "SRGB" else compose(gaussians, camera, mesh_rgba,
                                                        mesh_depth, color_space=space)
        buffer = np.empty(mesh_rgba.shape, np.float32)
        got = compose(gaussians, camera, view, mesh_depth, color_space=space, out=buffer[::-1])
        assert np.shares_memory(got.rgba, buffer)
        assert np.array_equal(buffer[::-1].view(np.uint32), want.rgba.view(np.uint32))
        assert np.array_equal(got.depth, want.depth)


def _compose_frame_wide(gaussians, camera, mesh_rgba, mesh_depth, threads):
    """compose() as three frame-wide passes (what it was before the tile pass): the whole layer
    to display sRGB, the native render over it, the changed pixels back."""
    layer = colour.display_from_linear(mesh_rgba, threads=threads, zero_non_finite=True)
    depth_in = np.nan_to_num(mesh_depth, nan=FAR, posinf=FAR, neginf=0.0).astype(np.float32)
    result = render(gaussians, camera, mesh_rgba=layer, mesh_depth=depth_in, threads=threads)
    out = np.empty_like(layer)
    native.srgb_decode_changed(result.rgb, result.alpha, mesh_rgba, layer, threads, out)
    depth = result.depth
    depth[~np.isfinite(depth)] = FAR
    return out, depth


@pytest.mark.parametrize("threads", [1, 3])
def test_compose_tile_by_tile_is_the_frame_wide_composite_bit_for_bit(rng, threads):
    """The tile pass (mesh pixels copied where no Gaussian reaches, converted and composed
    elsewhere) gives the bits of the frame-wide passes: colour and depth, with non-finite mesh
    values, odd image sizes (partial tiles) and Gaussians that leave tiles empty."""
    for width, height, count in ((67, 45, 12), (160, 96, 200), (33, 17, 0)):
        gaussians, camera = random_scene(rng, max(count, 1), width, height, 1)
        if count == 0:
            gaussians = gaussians.subset(np.zeros(len(gaussians), bool))
        mesh_rgba, mesh_depth = random_mesh_layer(rng, width, height)
        mesh_rgba[::7, ::3, 0] = np.nan
        mesh_rgba[::11, ::5, 3] = np.inf
        mesh_depth[::13, ::2] = np.nan
        mesh_depth[1::13, ::3] = -np.inf
        want_rgba, want_depth = _compose_frame_wide(gaussians, camera, mesh_rgba, mesh_depth,
                                                    threads)
        got = compose(gaussians, camera, mesh_rgba, mesh_depth, threads=threads)
        assert np.array_equal(got.rgba.view(np.uint32), want_rgba.view(np.uint32))
        assert np.array_equal(got.depth.view(np.uint32), want_depth.view(np.uint32))
        prepared = prepare(gaussians, camera, threads=threads)  # made ahead, used twice
        for _ in range(2):
            again = compose(gaussians, camera, mesh_rgba, mesh_depth, threads=threads,
                            prepared=prepared)
            assert np.array_equal(again.rgba.view(np.uint32), want_rgba.view(np.uint32))
            assert np.array_equal(again.depth.view(np.uint32), want_depth.view(np.uint32))
        with pytest.raises(ValueError, match="another camera"):
            compose(gaussians, copy.copy(camera), mesh_rgba, mesh_depth, prepared=prepared)
        colour_only = compose(gaussians, camera, mesh_rgba, mesh_depth, threads=threads,
                              with_depth=False)
        assert colour_only.depth is None
        assert np.array_equal(colour_only.rgba.view(np.uint32), want_rgba.view(np.uint32))
        if count:
            assert (got.rgba.view(np.uint32) != mesh_rgba.view(np.uint32)).any()


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
