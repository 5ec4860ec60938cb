"""The renderer's argument checks: bad arguments raise TypeError or ValueError naming the
problem, never crash (docs/guide/scripts.md): at the Python API (`addon.core.render.renderer`)
and directly at `splatcore`, whose positional signatures are what core/native.py passes."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from addon.core.render import renderer as api
from addon.core.cameras import Camera
from addon.core.gaussians import Gaussians
from tests.scenes import random_gaussians

N, W, H = 7, 20, 12


@pytest.fixture
def splatcore():
    import splatcore
    return splatcore


def _gaussian_arrays(degree=1):
    g = random_gaussians(np.random.default_rng(0), N, degree)
    return [g.means, g.log_scales, g.quats, g.opacity_logits, g.sh]


def _camera_arrays():
    viewmat = np.eye(4)
    viewmat[2, 3] = 4.0
    return viewmat, np.array([20.0, 20.0, W / 2, H / 2])


def project_args(**change):
    """splatcore.project's positional arguments, valid unless `change`d."""
    means, log_scales, quats, logits, sh = _gaussian_arrays()
    viewmat, intrinsics = _camera_arrays()
    args = dict(means=means, log_scales=log_scales, quats=quats, opacity_logits=logits, sh=sh,
                sh_degree=1, viewmat=viewmat, intrinsics=intrinsics, width=W, height=H, near=0.01,
                antialiased=False, threads=0, out_xy=np.zeros((N, 2), np.float32),
                out_conic=np.zeros((N, 3), np.float32), out_depth=np.zeros(N, np.float32),
                out_opacity=np.zeros(N, np.float32), out_rgb=np.zeros((N, 3), np.float32),
                out_valid=np.zeros(N, np.uint8))
    args.update(change)
    return list(args.values())


def render_args(**change):
    """splatcore.render's positional arguments, valid unless `change`d."""
    means, log_scales, quats, logits, sh = _gaussian_arrays()
    viewmat, intrinsics = _camera_arrays()
    args = dict(means=means, log_scales=log_scales, quats=quats, opacity_logits=logits, sh=sh,
                sh_degree=1, viewmat=viewmat, intrinsics=intrinsics, width=W, height=H, near=0.01,
                antialiased=False, threads=0, background=None, mesh_rgba=None, mesh_depth=None,
                out_rgb=np.zeros((H, W, 3), np.float32), out_alpha=np.zeros((H, W), np.float32),
                out_depth=np.zeros((H, W), np.float32))
    args.update(change)
    return list(args.values())


def _fortran(a):
    """The same values, not C-contiguous (a transposed copy viewed back)."""
    out = np.asfortranarray(a)
    assert not out.flags.c_contiguous
    return out


def _read_only(a):
    a = a.copy()
    a.flags.writeable = False
    return a


def test_valid_arguments_work(splatcore):
    # The baseline every case below changes one thing of.
    splatcore.project(*project_args())
    stats = splatcore.render(*render_args())
    assert isinstance(stats, dict)


MEANS, LOG_SCALES, QUATS, LOGITS, SH = _gaussian_arrays()
COMMON_CASES = {
    # name: (changes, exception, message keyword(s))
    "means_float64": (dict(means=MEANS.astype(np.float64)), TypeError, "float32"),
    "sh_float16": (dict(sh=SH.astype(np.float16)), TypeError, "float32"),
    "means_list": (dict(means=MEANS.tolist()), TypeError, "array"),
    "means_none": (dict(means=None), TypeError, "array"),
    "means_shape": (dict(means=MEANS[:, :2].copy()), ValueError, "shape"),
    "means_1d": (dict(means=MEANS.ravel()), ValueError, "shape"),
    "means_not_contiguous": (dict(means=_fortran(MEANS)), ValueError, "contiguous"),
    "means_strided": (dict(means=np.repeat(MEANS, 2, axis=0)[::2]), ValueError, "contiguous"),
    "quats_not_contiguous": (dict(quats=_fortran(QUATS)), ValueError, "contiguous"),
    "log_scales_rows": (dict(log_scales=LOG_SCALES[:-1].copy()), ValueError, "shape"),
    "quats_shape": (dict(quats=QUATS[:, :3].copy()), ValueError, "shape"),
    "opacity_rows": (dict(opacity_logits=LOGITS[:-1].copy()), ValueError, "shape"),
    "opacity_2d": (dict(opacity_logits=LOGITS[:, None].copy()), ValueError, "shape"),
    "sh_rows": (dict(sh=SH[:-1].copy()), ValueError, "shape"),
    "sh_k5": (dict(sh=np.zeros((N, 5, 3), np.float32)), ValueError, "shape"),
    "sh_channels": (dict(sh=np.zeros((N, 4, 4), np.float32)), ValueError, "shape"),
    "sh_degree_4": (dict(sh_degree=4), ValueError, "sh_degree"),
    "sh_degree_above_data": (dict(sh_degree=2), ValueError, "sh_degree"),
    "sh_degree_negative": (dict(sh_degree=-1), ValueError, "sh_degree"),
    "viewmat_shape": (dict(viewmat=np.eye(4)[:3].copy()), ValueError, "shape"),
    "viewmat_float32": (dict(viewmat=np.eye(4, dtype=np.float32)), TypeError, "float64"),
    "viewmat_nan": (dict(viewmat=np.where(np.eye(4) == 1, np.nan, 0.0)), ValueError, "non-finite"),
    "viewmat_not_rigid": (dict(viewmat=np.diag([2.0, 2.0, 2.0, 1.0])), ValueError, "rigid"),
    "intrinsics_shape": (dict(intrinsics=np.array([20.0, 20.0, 10.0])), ValueError, "shape"),
    "intrinsics_inf": (dict(intrinsics=np.array([np.inf, 20.0, 10.0, 6.0])), ValueError, "non-finite"),
    "focal_zero": (dict(intrinsics=np.array([0.0, 20.0, 10.0, 6.0])), ValueError, "focal"),
    "focal_negative": (dict(intrinsics=np.array([20.0, -20.0, 10.0, 6.0])), ValueError, "focal"),
    "width_zero": (dict(width=0), ValueError, "size"),
    "height_negative": (dict(height=-5), ValueError, "size"),
    "huge_image": (dict(width=100_000, height=100_000), ValueError, "size"),
    "too_many_pixels": (dict(width=30_000, height=30_000), ValueError, "size"),
    "near_nan": (dict(near=float("nan")), ValueError, "near"),
    "near_negative": (dict(near=-1.0), ValueError, "near"),
    "threads_negative": (dict(threads=-1), ValueError, "threads"),
    "width_not_int": (dict(width="20"), TypeError, "int"),
    "means_nan": (dict(means=np.where(np.arange(3 * N).reshape(N, 3) == 4, np.nan, MEANS).astype(np.float32)),
                  ValueError, "non-finite"),
    "log_scales_inf": (dict(log_scales=np.where(np.arange(3 * N).reshape(N, 3) == 0, np.inf,
                                                LOG_SCALES).astype(np.float32)), ValueError, "non-finite"),
}


@pytest.mark.parametrize("case", list(COMMON_CASES))
def test_native_project_rejects(splatcore, case):
    change, error, keyword = COMMON_CASES[case]
    with pytest.raises(error, match=keyword):
        splatcore.project(*project_args(**change))


@pytest.mark.parametrize("case", list(COMMON_CASES))
def test_native_render_rejects_common(splatcore, case):
    change, error, keyword = COMMON_CASES[case]
    with pytest.raises(error, match=keyword):
        splatcore.render(*render_args(**change))


PROJECT_OUT_CASES = {
    "out_xy_read_only": (dict(out_xy=_read_only(np.zeros((N, 2), np.float32))), ValueError, "writable"),
    "out_valid_read_only": (dict(out_valid=_read_only(np.zeros(N, np.uint8))), ValueError, "writable"),
    "out_conic_float64": (dict(out_conic=np.zeros((N, 3))), TypeError, "float32"),
    "out_valid_bool": (dict(out_valid=np.zeros(N, bool)), TypeError, "uint8"),
    "out_depth_rows": (dict(out_depth=np.zeros(N + 1, np.float32)), ValueError, "shape"),
    "out_rgb_not_contiguous": (dict(out_rgb=_fortran(np.zeros((N, 3), np.float32))), ValueError, "contiguous"),
    "out_xy_bytes": (dict(out_xy=bytes(N * 8)), ValueError, "writable"),
}


@pytest.mark.parametrize("case", list(PROJECT_OUT_CASES))
def test_native_project_rejects_outputs(splatcore, case):
    change, error, keyword = PROJECT_OUT_CASES[case]
    with pytest.raises(error, match=keyword):
        splatcore.project(*project_args(**change))


def _mesh(alpha=0.5, depth=3.0):
    rgba = np.full((H, W, 4), 0.25, np.float32)
    rgba[..., 3] = alpha
    return rgba, np.full((H, W), depth, np.float32)


RENDER_CASES = {
    "out_rgb_read_only": (dict(out_rgb=_read_only(np.zeros((H, W, 3), np.float32))), ValueError, "writable"),
    "out_depth_read_only": (dict(out_depth=_read_only(np.zeros((H, W), np.float32))), ValueError, "writable"),
    "out_alpha_float64": (dict(out_alpha=np.zeros((H, W))), TypeError, "float32"),
    "out_rgb_shape": (dict(out_rgb=np.zeros((W, H, 3), np.float32)), ValueError, "shape"),
    "out_alpha_shape": (dict(out_alpha=np.zeros((H, W, 1), np.float32)), ValueError, "shape"),
    "out_depth_not_contiguous": (dict(out_depth=np.zeros((H, 2 * W), np.float32)[:, ::2]), ValueError,
                                 "contiguous"),
    "background_shape": (dict(background=np.zeros(4, np.float32)), ValueError, "shape"),
    "background_float64": (dict(background=np.zeros(3)), TypeError, "float32"),
    "background_nan": (dict(background=np.float32([0, np.nan, 0])), ValueError, "non-finite"),
    "mesh_rgba_alone": (dict(mesh_rgba=_mesh()[0]), ValueError, "together"),
    "mesh_depth_alone": (dict(mesh_depth=_mesh()[1]), ValueError, "together"),
    "mesh_rgba_shape": (dict(mesh_rgba=_mesh()[0][..., :3].copy(), mesh_depth=_mesh()[1]), ValueError, "shape"),
    "mesh_depth_shape": (dict(mesh_rgba=_mesh()[0], mesh_depth=_mesh()[1].T.copy()), ValueError, "shape"),
    "mesh_rgba_float64": (dict(mesh_rgba=_mesh()[0].astype(np.float64), mesh_depth=_mesh()[1]), TypeError,
                          "float32"),
    "mesh_alpha_above_1": (dict(mesh_rgba=_mesh(alpha=1.5)[0], mesh_depth=_mesh()[1]), ValueError, "alpha"),
    "mesh_rgba_nan": (dict(mesh_rgba=np.where(np.arange(4) == 0, np.nan, _mesh()[0]).astype(np.float32),
                           mesh_depth=_mesh()[1]), ValueError, "non-finite"),
    "mesh_depth_nan": (dict(mesh_rgba=_mesh()[0], mesh_depth=_mesh(depth=np.nan)[1]), ValueError, "NaN"),
}


@pytest.mark.parametrize("case", list(RENDER_CASES))
def test_native_render_rejects(splatcore, case):
    change, error, keyword = RENDER_CASES[case]
    with pytest.raises(error, match=keyword):
        splatcore.render(*render_args(**change))


def test_native_wrong_argument_count(splatcore):
    with pytest.raises(TypeError):
        splatcore.render(*render_args()[:-1])
    with pytest.raises(TypeError):
        splatcore.project(*project_args(), None)


def test_native_outputs_untouched_or_whole_after_error(splatcore):
    # A rejected call leaves no NaN and no partial write behind in the output arrays.
    rgb = np.full((H, W, 3), 7.0, np.float32)
    with pytest.raises(ValueError):
        splatcore.render(*render_args(threads=-1, out_rgb=rgb))
    assert (rgb == 7).all()


# ---------------------------------------------------------------- the Python API


@pytest.fixture
def scene():
    g = random_gaussians(np.random.default_rng(1), N, 1)
    viewmat, intrinsics = _camera_arrays()
    return g, Camera(viewmat, *intrinsics, W, H)


def test_api_float64_arrays_are_converted_by_gaussians():
    g = Gaussians(*(a.astype(np.float64) for a in _gaussian_arrays()))
    assert all(a.dtype == np.float32 and a.flags.c_contiguous for a in g.arrays().values())


@pytest.mark.parametrize("field, value, error, keyword", [
    ("means", MEANS.astype(np.float64), TypeError, "float32"),
    ("quats", _fortran(QUATS), ValueError, "contiguous"),
    ("log_scales", LOG_SCALES[:-2].copy(), ValueError, "shape"),
    ("sh", SH[:, :3].copy(), ValueError, "shape"),
])
def test_api_arrays_changed_after_construction(scene, field, value, error, keyword):
    # The dataclass can be edited in place; the native layer still refuses bad arrays.
    g, cam = scene
    setattr(g, field, value)
    with pytest.raises(error, match=keyword):
        api.render(g, cam)
    with pytest.raises(error, match=keyword):
        api.project(g, cam)


@pytest.mark.parametrize("arrays, keyword", [
    (lambda a: [a[0][:, :2]] + a[1:], "shape"),
    (lambda a: a[:1] + [a[1][:-1]] + a[2:], "rows"),
    (lambda a: a[:4] + [np.zeros((N, 5, 3))], "shape"),
    (lambda a: a[:3] + [a[3][:, None]] + a[4:], "shape"),
])
def test_api_gaussians_constructor_rejects(arrays, keyword):
    with pytest.raises(ValueError, match=keyword):
        Gaussians(*arrays(_gaussian_arrays()))


def test_api_not_gaussians(scene):
    _, cam = scene
    with pytest.raises(TypeError, match="Gaussians"):
        api.render(_gaussian_arrays(), cam)


@pytest.mark.parametrize("width, height", [(0, 10), (10, 0), (-3, 10), (100_000, 100_000),
                                           (40_000, 8), (20_000, 20_000)])
def test_api_bad_image_size_before_allocating(scene, width, height):
    g, _ = scene
    viewmat, intrinsics = _camera_arrays()
    cam = Camera(viewmat, *intrinsics, width, height)
    tracemalloc.start()
    try:
        with pytest.raises(ValueError, match="size"):
            api.render(g, cam)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1 << 20, f"{peak} bytes allocated before refusing"


def test_api_options(scene):
    g, cam = scene
    with pytest.raises(ValueError, match="sh_degree"):
        api.render(g, cam, sh_degree=4)
    with pytest.raises(ValueError, match="sh_degree"):
        api.project(g, cam, sh_degree=-1)
    with pytest.raises(ValueError, match="threads"):
        api.render(g, cam, threads=-1)
    with pytest.raises(ValueError, match="threads"):
        api.project(g, cam, threads=-2)
    with pytest.raises(ValueError, match="near"):
        api.render(g, cam, near=float("nan"))
    with pytest.raises(ValueError, match="together"):
        api.render(g, cam, mesh_rgba=_mesh()[0])
    with pytest.raises(ValueError, match="shape"):
        api.render(g, cam, mesh_rgba=_mesh()[0][:-1], mesh_depth=_mesh()[1][:-1])
    with pytest.raises(ValueError, match="shape"):
        api.render(g, cam, mesh_rgba=_mesh()[0], mesh_depth=_mesh()[1][:, :-1])
    with pytest.raises(ValueError, match="shape"):
        api.render(g, cam, background=[0.1, 0.2])
    with pytest.raises(ValueError, match="alpha"):
        api.render(g, cam, mesh_rgba=_mesh(alpha=-0.5)[0], mesh_depth=_mesh()[1])


def test_api_camera_rejects():
    viewmat, _ = _camera_arrays()
    with pytest.raises(ValueError, match="non-finite"):
        Camera(np.full((4, 4), np.nan), 20, 20, 10, 6, W, H)
    with pytest.raises(ValueError, match="non-finite"):
        Camera(viewmat, 20, np.nan, 10, 6, W, H)
    with pytest.raises(ValueError, match="focal"):
        Camera(viewmat, 0, 20, 10, 6, W, H)
    with pytest.raises(ValueError, match="4x4"):
        Camera(np.eye(3), 20, 20, 10, 6, W, H)


def test_native_messages_fill_in_their_numbers(splatcore):
    """PyErr_Format knows no %g: these messages used to read "got %g" (issue 14)."""
    cases = [(dict(near=float("nan")), "near must be finite and >= 0, got nan"),
             (dict(near=-0.5), "got -0.5"),
             (dict(viewmat=np.diag([2.0, 1.0, 1.0, 1.0])), r"it is off by 3"),
             (dict(intrinsics=np.array([-20.0, 20.0, W / 2, H / 2])), "got fx=-20 fy=20")]
    for change, message in cases:
        with pytest.raises(ValueError, match=message) as info:
            splatcore.project(*project_args(**change))
        assert "%" not in str(info.value)
    image = np.zeros((8, 8, 3), np.float32)
    with pytest.raises(ValueError, match=r"got 1\.5") as info:
        splatcore.l1_ssim(image, image, 1.5, 0, np.zeros_like(image))
    assert "%" not in str(info.value)


@pytest.mark.parametrize("threads", [2**31, 2**64, -1])
def test_huge_thread_counts_are_a_value_error(splatcore, scene, threads):
    """threads=2**31 used to be an OverflowError from argument parsing."""
    g, cam = scene
    with pytest.raises(ValueError, match="threads must be >= 0"):
        api.render(g, cam, threads=threads)
    with pytest.raises(ValueError, match="threads must be >= 0"):
        splatcore.project(*project_args(threads=threads))
    image = np.zeros((8, 8, 3), np.float32)
    with pytest.raises(ValueError, match="threads must be >= 0"):
        splatcore.l1_ssim(image, image, 0.2, threads, np.zeros_like(image))


def test_depth_beyond_float32_is_never_valid(scene):
    """A camera translation beyond float32's range used to give valid Gaussians of infinite
    depth; they are culled now, and the render is empty."""
    g, _ = scene
    viewmat = np.eye(4)
    viewmat[2, 3] = 1e39
    cam = Camera(viewmat, 20, 20, W / 2, H / 2, W, H)
    projection = api.project(g, cam)
    assert not projection.valid.any()
    assert np.isfinite(projection.depth).all() and np.isfinite(projection.xy).all()
    rgb, alpha, depth = api.render(g, cam)
    assert not alpha.any() and np.isinf(depth).all()


@pytest.mark.parametrize("threads", [1, 2, 3, 0])
def test_the_first_non_finite_value_of_a_big_array_is_named(rng, threads):
    """FINITE arguments of a million values are scanned in chunks of 65,536 on the call's threads
    (native/src/finite.c): the error names the first bad index whatever chunk finds one first."""
    from addon.core.train import kernels

    image = rng.random((600, 600, 3), dtype=np.float32)  # 1,080,000 values: 17 chunks
    target = rng.random((600, 600, 3), dtype=np.float32)
    assert kernels.l1_ssim_loss(image, target, threads=threads).loss > 0
    flat = target.reshape(-1)
    flat[1_000_000] = np.inf   # a later chunk
    flat[700_001] = np.nan     # the first one
    flat[700_002] = -np.inf
    with pytest.raises(ValueError, match="target has a non-finite value .* at flat index 700001"):
        kernels.l1_ssim_loss(image, target, threads=threads)
    flat[700_001] = 1.0
    with pytest.raises(ValueError, match="at flat index 700002"):
        kernels.l1_ssim_loss(image, target, threads=threads)
