"""The native premultiplied sRGB conversions (native/src/colour.c, through
`addon.core.colour` for float32) against the transfer written out in float64."""

from __future__ import annotations

import numpy as np
import pytest

from addon.core import colour, native

# Each value is computed in double and rounded to float32 once: within half an ulp of the
# float64 formula, plus the table/series error (below 1e-11 relative). The bound asserted is
# 1 ulp of float32 (relative), with room for the last rounding.
ULPS = 1.0


def _transfer64(x: np.ndarray, decode: bool) -> np.ndarray:
    """colour.py's formulas in float64, written out here."""
    a = np.abs(x)
    with np.errstate(all="ignore"):
        if decode:
            y = np.where(a <= 0.04045, a / 12.92, ((a + 0.055) / 1.055) ** 2.4)
        else:
            y = np.where(a <= 0.0031308, 12.92 * a, 1.055 * a ** (1 / 2.4) - 0.055)
    return np.where(x < 0, -y, y)


def _premultiplied64(rgba: np.ndarray, decode: bool) -> np.ndarray:
    with np.errstate(all="ignore"):
        rgba = rgba.astype(np.float64)
        alpha = rgba[..., 3:]
        scale = np.where(alpha > 0, alpha, 1.0)
        out = _transfer64(rgba / scale, decode) * scale
    out[..., 3] = rgba[..., 3]
    return out


def _hard_values(rng) -> np.ndarray:
    cuts = [0.0031308, 0.04045]
    edges = [0.0, -0.0, 1.0, -1.0, 1e4, -1e4, 3e38, 1e-40, -1e-40, 1e-45, np.nan, np.inf,
             -np.inf, 0.5, 1e-8]
    around = [np.nextafter(np.float32(c), np.float32(d)) for c in cuts for d in (0, 1)]
    random = (rng.standard_normal(200_000) * np.exp(rng.uniform(-30, 12, 200_000)))
    return np.concatenate([edges, cuts, around, random]).astype(np.float32)


def _pixels(rng, values: np.ndarray) -> np.ndarray:
    n = -(-len(values) // 3)
    rgb = np.full(3 * n, 0.25, np.float32)
    rgb[:len(values)] = values
    rgba = np.empty((n, 4), np.float32)
    rgba[:, :3] = rgb.reshape(n, 3)
    rgba[:, 3] = rng.choice(np.array([1.0, 0.0, 0.5, 1e-3, 1e-30, np.nan, -1.0], np.float32), n)
    rgba[: n // 2, 3] = rng.random(n // 2)
    return rgba


@pytest.mark.parametrize("decode", [False, True])
def test_native_conversion_is_within_an_ulp_of_the_float64_transfer(rng, decode):
    rgba = _pixels(rng, _hard_values(rng))
    result = (colour.linear_from_display if decode else colour.display_from_linear)(rgba)
    expected = _premultiplied64(rgba, decode)
    with np.errstate(over="ignore"):
        expected32 = expected.astype(np.float32)
    finite = np.isfinite(expected32)
    # NaN stays NaN, infinities (and values beyond float32) are the same infinities
    assert np.array_equal(np.isnan(result), np.isnan(expected32))
    assert np.array_equal(result[~finite & ~np.isnan(expected32)],
                          expected32[~finite & ~np.isnan(expected32)])
    error = np.abs(result[finite].astype(np.float64) - expected[finite])
    ulp = np.spacing(np.abs(expected32[finite])).astype(np.float64)
    assert np.all(error <= ULPS * ulp + 1e-45), float((error / np.maximum(ulp, 1e-45)).max())
    assert np.array_equal(result[:, 3].view(np.uint32), rgba[:, 3].view(np.uint32))
    # -0 converts to +0, as in colour.py's NumPy transfer (the sign is put back only for x < 0)
    zero = np.array([[-0.0, 0.0, -0.0, 1.0]], np.float32)
    assert not np.signbit(colour.display_from_linear(zero)[0, :3]).any()


def test_native_round_trip_bound(rng):
    """linear -> display -> linear (mesh-only pixels, were they converted both ways) returns
    every finite value within 2 float32 ulps of what the float64 transfer's own round trip
    returns; compose does not convert them back at all. (The two are not the same: the sRGB
    pieces do not meet exactly at the cuts, so values just above 0.0031308 come back up to
    ~9 float32 ulps off in float64 too.) The bound: the display value is stored in float32
    (half an ulp, relative 2^-24 to 2^-25, which the decode's power 2.4 multiplies by up to 2.4,
    up to 2.4 ulps of the result) plus each conversion's own half ulp: 3.5 ulps."""
    rgba = _pixels(rng, _hard_values(rng))
    rgba = rgba[np.isfinite(rgba).all(axis=1) & (np.abs(rgba).max(axis=1) < 1e30)]
    assert len(rgba) > 60_000  # the hard values are in there
    back = colour.linear_from_display(colour.display_from_linear(rgba))
    expected = _premultiplied64(_premultiplied64(rgba, False), True)
    ulp = np.spacing(np.abs(rgba)).astype(np.float64)
    error = np.abs(back.astype(np.float64) - expected)
    assert np.all(error <= 3.5 * ulp + 1e-44), float((error / np.maximum(ulp, 1e-45)).max())


@pytest.mark.parametrize("decode", [False, True])
def test_native_conversion_is_the_same_on_any_thread_count_and_in_place(rng, decode):
    image = rng.standard_normal((123, 517, 4)).astype(np.float32) * 3
    image[..., 3] = rng.random((123, 517))
    image[::5, :, 3] = 1.0
    convert = colour.linear_from_display if decode else colour.display_from_linear
    one = convert(image, threads=1)
    for threads in (2, 3, 7):
        assert np.array_equal(convert(image, threads=threads).view(np.uint32), one.view(np.uint32))
    again = image.copy()
    assert convert(again, out=again, threads=3) is again
    assert np.array_equal(again.view(np.uint32), one.view(np.uint32))


def test_native_conversion_refuses_bad_arrays():
    module = native.splatcore()
    good = np.zeros((4, 4), np.float32)
    with pytest.raises(TypeError, match="float32"):
        module.srgb_premultiplied(good.astype(np.float64), good, False, 1)
    with pytest.raises(ValueError, match=r"\(\.\.\., 4\)"):
        module.srgb_premultiplied(np.zeros((4, 3), np.float32), np.zeros((4, 3), np.float32),
                                  False, 1)
    with pytest.raises(ValueError, match="shape"):
        module.srgb_premultiplied(good, np.zeros((5, 4), np.float32), False, 1)
    with pytest.raises(ValueError, match="C-contiguous"):
        module.srgb_premultiplied(np.zeros((4, 8), np.float32)[:, ::2], good, False, 1)
    with pytest.raises(ValueError, match="writable"):
        readonly = np.zeros((4, 4), np.float32)
        readonly.flags.writeable = False
        module.srgb_premultiplied(good, readonly, False, 1)
    with pytest.raises(ValueError, match="overlap"):
        flat = np.zeros(20, np.float32)
        module.srgb_premultiplied(flat[:16].reshape(4, 4), flat[4:].reshape(4, 4), False, 1)
    with pytest.raises(ValueError, match="threads"):
        module.srgb_premultiplied(good, good, False, -1)
    with pytest.raises(ValueError, match="out must be"):
        colour.display_from_linear(good, out=np.zeros((4, 4), np.float64))
    with pytest.raises(ValueError, match=r"\(\.\.\., 4\)"):
        colour.display_from_linear(np.zeros((4, 3), np.float32))
    # overlapping (not identical) out through colour.py converts from a copy
    flat = (np.arange(24, dtype=np.float32) / 24)
    src = flat[:16].reshape(4, 4).copy()
    expected = colour.display_from_linear(src)
    flat[:16] = src.reshape(-1)
    colour.display_from_linear(flat[:16].reshape(4, 4), out=flat[4:20].reshape(4, 4))
    assert np.array_equal(flat[4:20].reshape(4, 4), expected)


def test_decode_changed_is_the_decode_where_the_composite_differs(rng):
    """compose's way back: changed pixels (colour bits, or alpha by more than 1e-6) are the
    premultiplied decode of the composite; the others are the mesh pixel, bit for bit; the
    same on any thread count."""
    h, w = 97, 301
    mesh = rng.random((h, w, 4)).astype(np.float32)
    layer = colour.display_from_linear(mesh)
    rgb = layer[..., :3].copy()
    alpha = layer[..., 3].copy()
    touched = rng.random((h, w)) < 0.3
    rgb[touched] = rng.random((int(touched.sum()), 3)).astype(np.float32) * 2 - 0.2
    alpha[touched] = rng.random(int(touched.sum())).astype(np.float32)
    rounding = ~touched & (rng.random((h, w)) < 0.1)     # alpha off by rounding only
    alpha[rounding] = np.nextafter(alpha[rounding], np.float32(0))
    shifted = ~touched & ~rounding & (rng.random((h, w)) < 0.05)  # alpha off by more
    alpha[shifted] *= np.float32(0.5)
    rgb[0, 0, 1] = np.nan
    changed = touched | shifted
    changed[0, 0] = True
    expected = colour.linear_from_display(np.concatenate([rgb, alpha[..., None]], -1))
    results = []
    for threads in (1, 2, 5):
        out = layer.copy()
        native.srgb_decode_changed(rgb, alpha, mesh, out, threads)
        results.append(out)
        assert np.array_equal(out[~changed].view(np.uint32), mesh[~changed].view(np.uint32))
        assert np.array_equal(out[changed].view(np.uint32), expected[changed].view(np.uint32))
    assert all(np.array_equal(r.view(np.uint32), results[0].view(np.uint32)) for r in results)
    with pytest.raises(ValueError, match="overlap"):
        native.srgb_decode_changed(rgb, alpha, layer, layer, 1)
    with pytest.raises(ValueError, match="shape"):
        native.srgb_decode_changed(rgb, alpha[:-1], mesh, layer.copy(), 1)


def test_views_with_any_strides_convert_like_contiguous_pixels(rng):
    """srgb_view reads and writes (H, W, 4) views with any strides (an EXR's planar channels,
    in reverse channel order; a row-reversed buffer), gives pixels bit-identical to their left
    neighbour that neighbour's result (runs of a flat background), and zeroes non-finite
    results when asked; the same bits as the contiguous conversion, on any thread count."""
    h, w = 53, 301
    rgba = np.empty((h, w, 4), np.float32)
    rgba[..., :3] = _hard_values(rng)[: h * w * 3].reshape(h, w, 3)
    rgba[..., 3] = rng.choice(np.array([1.0, 0.0, 0.5, 1e-30, np.nan, -1.0], np.float32), (h, w))
    rgba[5:9] = rgba[5, 0]                       # runs, across rows
    rgba[20, 10:200] = [np.nan, 0.5, 0.25, 1.0]  # a run of NaN
    rgba[30:40, :, 3] = 1.0
    for decode in (False, True):
        convert = colour.linear_from_display if decode else colour.display_from_linear
        expected = convert(np.ascontiguousarray(rgba), threads=1)
        assert np.array_equal(expected.view(np.uint32),
                              convert(rgba.reshape(-1, 4), threads=1).reshape(h, w, 4)
                              .view(np.uint32))
        planar = np.ascontiguousarray(rgba[..., ::-1].transpose(0, 2, 1))  # rows of A, B, G, R
        view = np.lib.stride_tricks.as_strided(planar[:, 3], (h, w, 4), (planar.strides[0], 4,
                                               -planar.strides[1]), writeable=False)
        assert np.array_equal(view.view(np.uint32), rgba.view(np.uint32))
        for threads in (1, 3):
            flipped = np.full((h, w, 4), 7.0, np.float32)
            native.srgb_view(view, flipped[::-1], decode, False, threads)
            assert np.array_equal(flipped[::-1].view(np.uint32), expected.view(np.uint32))
            finite = np.empty((h, w, 4), np.float32)
            native.srgb_view(view, finite, decode, True, threads)
            want = np.nan_to_num(expected, nan=0.0, posinf=0.0, neginf=0.0)
            assert np.array_equal(finite.view(np.uint32), want.view(np.uint32))
    with pytest.raises(ValueError, match="shape"):
        native.srgb_view(view, np.empty((h, w - 1, 4), np.float32), False, False, 1)
    with pytest.raises(ValueError, match="overlap"):
        buffer = np.zeros((h + 1, w, 4), np.float32)
        native.srgb_view(buffer[1:], buffer[:-1], False, False, 1)
    with pytest.raises(ValueError, match="writable"):
        native.srgb_view(rgba, view, False, False, 1)


def test_decode_changed_writes_any_view_and_reads_the_mesh_through_one(rng):
    """The way back can write a separate (here row-reversed) image and read the mesh layer as a
    strided view: the same bits as in place over contiguous arrays."""
    h, w = 31, 67
    mesh = rng.random((h, w, 4)).astype(np.float32)
    layer = colour.display_from_linear(mesh)
    rgb = layer[..., :3].copy()
    alpha = layer[..., 3].copy()
    touched = rng.random((h, w)) < 0.3
    rgb[touched] = rng.random((int(touched.sum()), 3)).astype(np.float32)
    expected = layer.copy()
    native.srgb_decode_changed(rgb, alpha, mesh, expected, 1)
    planar = np.ascontiguousarray(mesh.transpose(0, 2, 1))
    view = np.lib.stride_tricks.as_strided(planar, (h, w, 4), (planar.strides[0], 4, 4 * w),
                                           writeable=False)
    for threads in (1, 2):
        out = np.empty((h, w, 4), np.float32)
        native.srgb_decode_changed(rgb, alpha, view, layer, threads, out[::-1])
        assert np.array_equal(out[::-1].view(np.uint32), expected.view(np.uint32))
    with pytest.raises(ValueError, match="overlap"):
        native.srgb_decode_changed(rgb, alpha, mesh, layer, 1, mesh)
    with pytest.raises(ValueError, match="overlap"):
        both = np.zeros((h + 1, w, 4), np.float32)
        native.srgb_decode_changed(rgb, alpha, mesh, both[1:], 1, both[:-1])
