"""Blender 5.3's splat attributes <-> Gaussians (addon/core/blender_splats/attributes.py)."""

from __future__ import annotations

import numpy as np
import pytest

from addon.core.blender_splats import attributes
from addon.core.gaussians import Gaussians


def _random(rng: np.random.Generator, n: int, degree: int) -> Gaussians:
    return Gaussians(rng.normal(0, 3, (n, 3)), rng.normal(-3, 1.5, (n, 3)), rng.normal(0, 1, (n, 4)),
                     rng.normal(0, 4, n), rng.normal(0, 0.5, (n, (degree + 1) ** 2, 3)))


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-x.astype(np.float64)))


def _assert_same(a: Gaussians, b: Gaussians) -> None:
    """Equal up to float32 rounding of exp/log and sigmoid/logit (opacity compared as opacity)."""
    assert a.degree == b.degree and len(a) == len(b)
    np.testing.assert_array_equal(a.means, b.means)
    np.testing.assert_array_equal(a.quats, b.quats)
    np.testing.assert_array_equal(a.sh, b.sh)
    np.testing.assert_allclose(a.log_scales, b.log_scales, rtol=0, atol=3e-7)
    np.testing.assert_allclose(_sigmoid(a.opacity_logits), _sigmoid(b.opacity_logits), rtol=0, atol=1.2e-7)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_round_trip_ours_blender_ours(rng, degree):
    ours = _random(rng, 500, degree)
    arrays = attributes.attributes_from_gaussians(ours)
    assert set(arrays) == {"position", "scale", "rotation", "radiance:base"} | set(attributes.sh_names(degree))
    back = attributes.gaussians_from_attributes(arrays)
    assert back.dropped == 0 and back.warnings == [] and back.source_degree == degree
    _assert_same(ours, back.gaussians)


def test_round_trip_blender_ours_blender(rng):
    n = 400
    arrays = {"position": rng.normal(0, 2, (n, 3)).astype(np.float32),
              "scale": np.exp(rng.normal(-3, 1, (n, 3))).astype(np.float32),
              "rotation": rng.normal(0, 1, (n, 4)).astype(np.float32),
              "radiance:base": np.concatenate([rng.normal(0, 1, (n, 3)), rng.uniform(0.001, 0.999, (n, 1))], 1)
              .astype(np.float32)}
    for name in attributes.sh_names(3):
        arrays[name] = rng.normal(0, 0.3, (n, 3)).astype(np.float32)
    back = attributes.attributes_from_gaussians(attributes.gaussians_from_attributes(arrays).gaussians)
    for name, value in arrays.items():
        tolerance = 0 if name not in ("scale", "radiance:base") else 3e-7
        np.testing.assert_allclose(back[name], value, rtol=tolerance, atol=tolerance * 1e-3, err_msg=name)


def test_the_convention_by_hand():
    """One splat written out by hand: exp scale, sigmoid opacity in w, SH DC in xyz, sh_j = ours j+1."""
    sh = np.arange(16 * 3, dtype=np.float32).reshape(1, 16, 3) / 100
    g = Gaussians([[1, 2, 3]], [[0.0, np.log(2), np.log(0.5)]], [[0.5, 0.5, -0.5, 0.5]], [0.0], sh)
    a = attributes.attributes_from_gaussians(g)
    np.testing.assert_allclose(a["scale"], [[1, 2, 0.5]], rtol=1e-7)
    np.testing.assert_array_equal(a["radiance:base"], np.float32([[0, 0.01, 0.02, 0.5]]))
    np.testing.assert_array_equal(a["rotation"], [[0.5, 0.5, -0.5, 0.5]])
    np.testing.assert_array_equal(a["radiance:sh_0"], sh[:, 1])
    np.testing.assert_array_equal(a["radiance:sh_14"], sh[:, 15])
    assert "radiance:sh_15" not in a


def test_degree_4_reads_as_3_with_a_warning(rng):
    n = 10
    arrays = attributes.attributes_from_gaussians(_random(rng, n, 3))
    for name in attributes.sh_names(4)[15:]:
        arrays[name] = rng.normal(size=(n, 3)).astype(np.float32)
    out = attributes.gaussians_from_attributes(arrays)
    assert out.source_degree == 4 and out.gaussians.degree == 3
    assert any("degree 4" in w for w in out.warnings)


def test_incomplete_band_is_dropped_with_a_warning(rng):
    arrays = attributes.attributes_from_gaussians(_random(rng, 5, 2))
    del arrays["radiance:sh_7"]  # band 2 incomplete
    out = attributes.gaussians_from_attributes(arrays)
    assert out.gaussians.degree == 1
    assert any("radiance:sh_3" in w for w in out.warnings)


@pytest.mark.parametrize("missing", ["position", "scale", "rotation", "radiance:base"])
def test_missing_attribute_is_a_clear_error(rng, missing):
    arrays = attributes.attributes_from_gaussians(_random(rng, 5, 0))
    del arrays[missing]
    with pytest.raises(attributes.BlenderSplatError, match=missing):
        attributes.gaussians_from_attributes(arrays, source="cloud.ply")


def test_wrong_length_is_a_clear_error(rng):
    arrays = attributes.attributes_from_gaussians(_random(rng, 5, 1))
    arrays["radiance:sh_1"] = arrays["radiance:sh_1"][:3]
    with pytest.raises(attributes.BlenderSplatError, match="radiance:sh_1"):
        attributes.gaussians_from_attributes(arrays)


def test_non_finite_points_are_dropped_and_counted(rng):
    n = 50
    arrays = attributes.attributes_from_gaussians(_random(rng, n, 1))
    bad = rng.choice(n, 7, replace=False)
    for i, name in zip(bad, ["position", "scale", "rotation", "radiance:base", "radiance:sh_2", "scale", "position"]):
        arrays[name][i, 0] = [np.nan, np.inf, -np.inf][i % 3]
    out = attributes.gaussians_from_attributes(arrays)
    assert out.dropped == len(set(bad.tolist())) and len(out.gaussians) == n - out.dropped
    assert out.kept is not None and not out.kept[bad].any()
    assert out.gaussians.non_finite() is None and any("NaN or Inf" in w for w in out.warnings)


def test_saturated_opacity_and_zero_scale_stay_finite():
    arrays = {"position": np.zeros((3, 3), np.float32), "scale": np.array([[0, -2, 1]] * 3, np.float32),
              "rotation": np.array([[1, 0, 0, 0]] * 3, np.float32),
              "radiance:base": np.array([[0, 0, 0, 1], [0, 0, 0, 0], [0, 0, 0, 0.5]], np.float32)}
    g = attributes.gaussians_from_attributes(arrays).gaussians
    assert g.non_finite() is None
    np.testing.assert_allclose(np.exp(g.log_scales[0, 1:]), [2, 1], rtol=1e-7)
    np.testing.assert_allclose(_sigmoid(g.opacity_logits), [1, 0, 0.5], atol=1e-7)
    # the large logit a float32 opacity of 1.0 stands for still renders as fully opaque
    assert g.opacity_logits[0] > 16


def test_huge_log_scale_stays_finite_and_non_finite_input_is_refused(rng):
    g = _random(rng, 3, 0)
    g.log_scales[0, 0] = 200
    assert np.isfinite(attributes.attributes_from_gaussians(g)["scale"]).all()
    g.means[1, 1] = np.nan
    with pytest.raises(ValueError, match="means"):
        attributes.attributes_from_gaussians(g)


def test_sh_names_and_degree():
    assert attributes.sh_names(0) == () and len(attributes.sh_names(3)) == 15 and len(attributes.sh_names(4)) == 24
    assert attributes.degree_of(frozenset(attributes.sh_names(2)))[0] == 2
    with pytest.raises(ValueError):
        attributes.sh_names(5)


@pytest.mark.parametrize("name", ["position", "rotation", "radiance:base", "radiance:sh_2"])
@pytest.mark.parametrize("kind", ["object", "dict", "structured", "str", "bytes", "complex", "ragged", "shape"])
def test_an_attribute_of_another_dtype_or_shape_is_an_error_naming_it(rng, name, kind):
    """Object, dict, structured and string arrays raised a raw TypeError or a bare numpy
    ValueError naming nothing; a (N, 2, 2) array of the right size was silently reshaped."""
    arrays = attributes.attributes_from_gaussians(_random(rng, 5, 1))
    good = arrays[name]
    arrays[name] = {
        "object": np.array([object()] * good.size, dtype=object),
        "dict": np.array([{"x": 1}] * len(good), dtype=object),
        "structured": np.zeros(len(good), dtype=[("a", "f4"), ("b", "f4", (good.shape[1] - 1,))]),
        "str": good.astype(str),
        "bytes": good.astype("S8"),
        "complex": good.astype(np.complex64),
        "ragged": [[1.0, 2.0], [3.0]],
        "shape": good.reshape(len(good), 1, -1) if name != "rotation" else good.reshape(len(good), 2, 2),
    }[kind]
    with pytest.raises(attributes.BlenderSplatError, match=f"cloud.ply: attribute '{name}'"):
        attributes.gaussians_from_attributes(arrays, source="cloud.ply")


def test_integer_attributes_are_numbers(rng):
    arrays = attributes.attributes_from_gaussians(_random(rng, 5, 0))
    arrays["position"] = np.rint(arrays["position"]).astype(np.int16)
    assert attributes.gaussians_from_attributes(arrays).gaussians.means.dtype == np.float32
