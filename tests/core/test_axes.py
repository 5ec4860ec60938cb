"""Forward / Up axis options of splat import and export (core.axes, blender.io.operators)."""

from __future__ import annotations

import itertools

import bpy_support as bs
from bpy_support import bpy  # the shared bpy import
import numpy as np
import pytest
from bpy_extras.io_utils import axis_conversion

from addon.blender.io import operators
from addon.core import axes, splat_io
from addon.core.formats import registry
from scenes import random_gaussians


@pytest.fixture(autouse=True)
def empty_scene():
    bs.reset_scene()
    yield


def test_axis_matrix_is_blenders_axis_conversion():
    pairs = 0
    for forward, up in itertools.product(axes.AXES, repeat=2):
        if forward[-1] == up[-1]:
            with pytest.raises(ValueError):
                axes.axis_matrix(forward, up)
            continue
        expected = np.array(axis_conversion(from_forward=forward, from_up=up), np.float64)
        assert np.array_equal(axes.axis_matrix(forward, up), expected), (forward, up)
        pairs += 1
    assert pairs == 24
    assert axes.parse_axis("-y") == "-Y" and axes.parse_axis("+Z") == "Z"
    with pytest.raises(ValueError, match="unknown axis"):
        axes.parse_axis("W")


def test_every_format_has_valid_default_axes():
    for fmt in registry.FORMATS:
        assert axes.axis_matrix(*fmt.axes).shape == (3, 3), fmt.name


def _ground_normal(means: np.ndarray) -> np.ndarray:
    """Smallest-variance axis of the lowest 20 % of points (by world Z), pointing up."""
    low = means[means[:, 2] <= np.quantile(means[:, 2], 0.2)]
    values, vectors = np.linalg.eigh(np.cov((low - low.mean(axis=0)).T))
    normal = vectors[:, 0]
    return normal if normal[2] >= 0 else -normal


def test_playbot_stands_upright_with_default_axes(shared_data):
    obj = operators.import_splats(shared_data / "splats" / "playbot_125k_sh2.ply")
    world = np.array(obj.matrix_world, np.float64)
    means = bs.mesh_gaussians(obj).means.astype(np.float64) @ world[:3, :3].T + world[:3, 3]
    angle = np.degrees(np.arccos(np.clip(_ground_normal(means)[2], -1.0, 1.0)))
    print(f"playbot ground normal {angle:.2f} degrees from +Z")
    assert angle < 10.0
    # and the data is what the file holds: the conversion is the object's transform
    assert bs.gaussians_equal(bs.mesh_gaussians(obj), splat_io.load(
        shared_data / "splats" / "playbot_125k_sh2.ply"))


@pytest.mark.parametrize("forward,up", [("AUTO", "AUTO"), ("X", "Z"), ("-Z", "Y")])
def test_import_export_with_the_same_axes_is_bit_exact(rng, tmp_path, forward, up):
    source = tmp_path / "in.ply"
    splat_io.save(random_gaussians(rng, 200, 3), source)
    assert bpy.ops.splat.import_splats(filepath=str(source), forward_axis=forward,
                                       up_axis=up) == {"FINISHED"}
    out = tmp_path / "out.ply"
    assert bpy.ops.splat.export_splats(filepath=str(out), forward_axis=forward,
                                       up_axis=up) == {"FINISHED"}
    assert out.read_bytes() == source.read_bytes()


def test_export_axes_rotate_positions_and_sh(rng, tmp_path):
    """Exporting with other axes is the rotation `axis_matrix^-1` applied to the world-space
    splats, SH included (checked by the colour each shows along matching directions)."""
    from addon.core.transform import sh_basis

    g = random_gaussians(rng, 50, 3)
    source = tmp_path / "in.ply"
    splat_io.save(g, source)
    obj = operators.import_splats(source, forward_axis="Y", up_axis="Z")  # identity
    out = tmp_path / "out.ply"
    operators.export_splats(obj, out, forward_axis="Z", up_axis="-Y")
    back = splat_io.load(out)
    m = axes.axis_matrix("Z", "-Y")  # file -> Blender
    assert np.allclose(back.means @ m.T, g.means, atol=1e-5)
    dirs = rng.normal(size=(20, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    # colour along Blender direction d from the original == along file direction m^T d
    before = np.einsum("mk,nkc->nmc", sh_basis(dirs), g.sh.astype(np.float64))
    after = np.einsum("mk,nkc->nmc", sh_basis(dirs @ m), back.sh.astype(np.float64))
    assert np.abs(before - after).max() < 1e-4


def test_bad_axes_are_reported(tmp_path, rng):
    source = tmp_path / "in.ply"
    splat_io.save(random_gaussians(rng, 5, 0), source)
    before = bs.scene_state()
    with pytest.raises(RuntimeError, match="must be different axes"):
        bpy.ops.splat.import_splats(filepath=str(source), forward_axis="Z", up_axis="-Z")
    assert bs.scene_state() == before
