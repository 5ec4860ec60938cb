"""Assertions that hold native results against tests/reference.py, with the tolerances stated
once. Every check fails on NaN (comparisons are written as `all(err <= tol)`)."""

from __future__ import annotations

import numpy as np

# Rendered images (docs/conventions.md, "Rendering semantics"): the native float32 renderer
# matches the float64 reference to 1e-4 absolute on colours and alpha, and expected depth to
# 1e-4 relative (more where alpha moved, see below), except at `ambiguous` pixels (a
# threshold within float32 rounding, see reference.render), which must be rare: under 1% of the
# image (or 4 pixels in a tiny image). A float32 NumPy twin of the reference differs from it by
# about 2e-6.
RGB_ATOL = 1e-4
ALPHA_ATOL = 1e-4
DEPTH_RTOL = 1e-4
MAX_AMBIGUOUS = 0.01
# Expected depth is the pixel's weighted depths summed over its alpha, both from the same
# weights: rounding that moves alpha by a relative d moves the sum about as much, so depth
# may differ by DEPTH_RTOL plus twice alpha's own relative difference at that pixel (near a
# cube-map face's edge, in about 1 scene of 40: alpha off by 1.5e-4 and 2.5e-4 relative, depth
# by 1.1e-4).

# Projection: float32 rounding, ~8 ulps, scaled by how each quantity is conditioned. A float32
# NumPy twin stays below a tenth of these on random scenes.
UNIT = 1e-5


def _worst(err: np.ndarray, tol, mask: np.ndarray | None = None) -> str:
    ratio = np.where(np.isnan(err), np.inf, err / tol)
    if mask is not None:
        ratio = np.where(mask, ratio, -np.inf)
    index = np.unravel_index(np.argmax(ratio), ratio.shape)
    return f"worst at {index}: error {err[index]!r} vs tolerance {np.broadcast_to(tol, err.shape)[index]!r}"


def assert_images_match(got, want: dict, *, rgb_atol=RGB_ATOL, alpha_atol=ALPHA_ATOL,
                        depth_rtol=DEPTH_RTOL, max_ambiguous=MAX_AMBIGUOUS) -> None:
    """`got` a RenderResult (or (rgb, alpha, depth)), `want` a reference.render() dict."""
    rgb, alpha, depth = got
    height, width = want["alpha"].shape
    assert rgb.shape == (height, width, 3) and alpha.shape == (height, width)
    assert depth.shape == (height, width)
    assert rgb.dtype == alpha.dtype == depth.dtype == np.float32
    assert not np.isnan(rgb).any() and not np.isnan(alpha).any() and not np.isnan(depth).any()
    assert np.isfinite(rgb).all() and np.isfinite(alpha).all()
    assert np.all((alpha >= 0) & (alpha <= 1)), "alpha outside [0, 1]"

    ambiguous = want["ambiguous"]
    allowed = max(max_ambiguous * ambiguous.size, 4)  # tiny images: a few pixels
    assert ambiguous.sum() <= allowed, f"{ambiguous.mean():.4f} of the pixels are ambiguous"
    ok = ~ambiguous

    err = np.abs(rgb - want["rgb"]).max(axis=2)
    assert np.all(err[ok] <= rgb_atol), "rgb: " + _worst(err, rgb_atol, ok) + _pixel(got, want, err, ok)
    err = np.abs(alpha - want["alpha"])
    assert np.all(err[ok] <= alpha_atol), "alpha: " + _worst(err, alpha_atol, ok) + _pixel(got, want, err, ok)

    inf_got, inf_want = np.isinf(depth), np.isinf(want["depth"])
    assert np.all(inf_got[ok] == inf_want[ok]), \
        f"depth: inf at different pixels, e.g. {np.argwhere(ok & (inf_got != inf_want))[:5].tolist()}"
    assert np.all(depth[inf_got] > 0), "depth: -inf"
    finite = ok & ~inf_want
    with np.errstate(invalid="ignore", divide="ignore"):
        err = np.abs(depth.astype(np.float64) - want["depth"])
        alpha_moved = np.abs(alpha - want["alpha"]) / want["alpha"]
        tol = np.abs(want["depth"]) * (depth_rtol + 2.0 * alpha_moved)
    assert np.all(err[finite] <= tol[finite]), "depth: " + _worst(err, np.where(finite, tol, 1), finite)


def _pixel(got, want, err, ok) -> str:
    rgb, alpha, depth = got
    ratio = np.where(ok, np.nan_to_num(err, nan=np.inf), -np.inf)
    j, i = np.unravel_index(np.argmax(ratio), ratio.shape)
    return (f"\n  pixel row {j} col {i}: native rgb {rgb[j, i]} alpha {alpha[j, i]} depth {depth[j, i]}"
            f"\n  reference rgb {want['rgb'][j, i]} alpha {want['alpha'][j, i]} depth {want['depth'][j, i]}")


def assert_projection_matches(got, want: dict, means, viewmat, fx, fy, cx, cy, *, unit=UNIT,
                              opacity_atol=1e-5, rgb_atol=1e-5) -> None:
    """`got` an addon.core.render.renderer.Projection, `want` a reference.project() dict.

    Tolerances, per Gaussian, with u = `unit`, s = |mean| + |t| (the size of what the view
    transform adds up) and k = max(1, s / z) (how much z's rounding is amplified by 1/z):
      depth  |dz|  <= u s
      xy     |dxy| <= u (f k (1 + |xy - c| / f) + |xy|)
      conic  |dA|, |dB|, |dC| <= u k cond lmax, with lmax, cond the conic's largest eigenvalue
             and condition number (inverting amplifies rounding by the condition number)
      opacity, rgb: absolute (values of order 1).
    `valid` must agree exactly except within u s of the near plane (no such case in random scenes).
    """
    valid = want["valid"]
    np.testing.assert_array_equal(got.valid, valid, "valid differs")
    for name in ("xy", "conic", "depth", "opacity", "rgb"):
        array = getattr(got, name)
        assert array.dtype == np.float32, f"{name} is {array.dtype}"
        assert not np.isnan(array).any(), f"{name} has NaN"
        assert np.all(array[~valid] == 0), f"{name} is not zero on invalid rows"

    means = np.asarray(means, np.float64)
    scale = np.linalg.norm(means, axis=1) + np.linalg.norm(np.asarray(viewmat)[:3, 3])
    z = np.where(valid, want["depth"], 1.0)
    k = np.maximum(1.0, scale / z)
    f, c = np.array([fx, fy]), np.array([cx, cy])
    a, b, cc = want["conic"].T
    half_trace = (a + cc) / 2
    disc = np.sqrt(np.maximum(0.0, half_trace ** 2 - (a * cc - b * b)))
    lmax, lmin = half_trace + disc, np.maximum(half_trace - disc, 1e-300)

    v = valid
    checks = {
        "depth": (np.abs(got.depth - want["depth"]), unit * scale),
        "xy": (np.abs(got.xy - want["xy"]),
               unit * (f * k[:, None] * (1 + np.abs(want["xy"] - c) / f) + np.abs(want["xy"]))),
        "conic": (np.abs(got.conic - want["conic"]), (unit * k * (lmax / lmin) * lmax)[:, None]),
        "opacity": (np.abs(got.opacity - want["opacity"]), opacity_atol),
        "rgb": (np.abs(got.rgb - want["rgb"]), rgb_atol),
    }
    for name, (err, tol) in checks.items():
        tol = np.broadcast_to(tol, err.shape)
        ok = err <= tol
        rows_ok = ok.reshape(len(v), -1).all(axis=1) | ~v
        if not rows_ok.all():
            ratio = np.where(np.isnan(err), np.inf, err / tol).reshape(len(v), -1).max(axis=1)
            row = int(np.argmax(np.where(v, ratio, -np.inf)))
            raise AssertionError(
                f"{name}: {np.count_nonzero(~rows_ok)} Gaussians out of tolerance; worst #{row}: "
                f"native {getattr(got, name)[row]!r} reference {want[name][row]!r} "
                f"tolerance {tol[row]!r} (xy {want['xy'][row]}, depth {want['depth'][row]})")


# Renders of one scene in two frames (tests/core/test_transform.py): equal up to float rounding,
# except pixels where a threshold flips under rounding: at most 0.5 % of them, each bounded. A
# flip can hide under the colour tolerance and still move the expected depth Σwz/Σw (a Gaussian at
# alpha 1/255 behind an almost opaque pixel), so depth beyond DEPTH_RTOL counts as a flip too;
# elsewhere depth must agree far better (`depth_rel`, the 99.5th percentile).
RENDER_ATOL = 2e-4
RENDER_FLIP_ATOL = 0.05
MAX_FLIP_FRACTION = 0.005


def compare_renders(a, b, depth_scale: float = 1.0, atol: float = RENDER_ATOL) -> dict[str, float]:
    """`atol`: what a pixel that did not flip may differ by (RENDER_ATOL covers two frames' float
    rounding; the same frame computed twice may ask for less)."""
    err = np.maximum(np.abs(a.rgb - b.rgb).max(axis=2), np.abs(a.alpha - b.alpha))
    hit = np.isfinite(a.depth) & np.isfinite(b.depth)
    depth_err = np.where(np.isfinite(a.depth) == np.isfinite(b.depth), 0.0, np.inf)
    depth_err[hit] = np.abs(b.depth[hit] / depth_scale - a.depth[hit]) / a.depth[hit]
    flips = (err > atol) | (depth_err > DEPTH_RTOL)
    assert flips.mean() <= MAX_FLIP_FRACTION, f"{flips.sum()} pixels differ by more than {atol}"
    assert err.max() <= RENDER_FLIP_ATOL, f"worst error {err.max()}"
    return {"max": float(err.max()), "p99.5": float(np.quantile(err, 0.995)),
            "depth_rel": float(np.quantile(depth_err[hit], 0.995)) if hit.any() else 0.0,
            "flipped": int(flips.sum())}
