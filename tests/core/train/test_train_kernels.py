"""The loss, optimizer and noise kernels (`addon.core.train.kernels.l1_ssim_loss`, `adam_step`,
`position_noise`) against float64 NumPy references (tests/reference_backward.py).

Tolerances: the loss kernel works in float32 (as the 3DGS training code does on the GPU), with
the image means summed in double. L1 is exact differences of the float32 inputs summed in double:
1e-10 relative. SSIM: the variance s1 = w*x^2 - mu1^2 cancels in float32, with an error of a few
float32 ulps of mu1^2 <= 1 against a denominator s1 + s2 + C2 >= C2 = 9e-4, so per pixel ~1e-4
relative at worst (flat regions, where the variance is far below C2), ~1e-7 on textured images;
measured: the mean SSIM within 3e-6 absolute and the gradient within 1.2e-4 of its largest element
on flat images, 1e-6 on random ones. The tests allow 1e-5 absolute on SSIM, 2e-5 of the largest
gradient element on random images and 5e-4 on flat ones. The reference's own analytic SSIM
gradient is held against central finite differences (1e-6 relative). Adam works in float32 like
torch: 1e-5 relative per step. The position noise is double inside, rounded once to float32 when
added to the float32 mean: within a float32 ulp of the step and one of the sum."""

from __future__ import annotations

import numpy as np
import pytest

from addon.core.train import kernels
from tests import reference_backward as rb

SIZES = [(23, 17), (16, 16), (5, 3), (1, 1), (40, 9), (7, 600)]  # 600: several column chunks


def _images(rng, height, width):
    image = rng.uniform(0, 1, (height, width, 3)).astype(np.float32)
    # A target related to the image (as in training), never exactly equal (the L1 kink).
    target = np.clip(image + rng.normal(0, 0.1, image.shape), 0, 1).astype(np.float32)
    target[target == image] += np.float32(1e-3)
    return image, target


def test_reference_ssim_gradient_matches_finite_differences(rng):
    image, target = (a.astype(np.float64) for a in _images(rng, 9, 13))
    _, _, _, grad = rb.l1_ssim_loss(image, target, lambda_dssim=1.0)
    h = 1e-6
    for index in zip(*(rng.integers(0, n, 25) for n in image.shape)):
        up, down = image.copy(), image.copy()
        up[index] += h
        down[index] -= h
        fd = (rb.l1_ssim_loss(up, target, 1.0)[0] - rb.l1_ssim_loss(down, target, 1.0)[0]) / (2 * h)
        # Rounding floor of the difference quotient: ~1e-16 * loss / h.
        assert abs(grad[index] - fd) <= 1e-6 * abs(fd) + 1e-9, (index, grad[index], fd)


def test_reference_filter_is_torch_conv2d_with_zero_padding():
    # A unit impulse in a corner gives back the window's visible quarter; the window sums to 1.
    window = rb.gaussian_window()
    assert abs(window.sum() - 1) < 1e-15
    impulse = np.zeros((7, 8))
    impulse[0, 0] = 1
    want = np.zeros((7, 8))
    want[:6, :6] = window[5:, 5:]
    np.testing.assert_allclose(rb.filter2d(impulse, window), want, atol=1e-17)


@pytest.mark.parametrize("size", SIZES)
@pytest.mark.parametrize("lam", [0.0, 0.2, 1.0])
def test_loss_and_gradient_match_reference(rng, size, lam):
    image, target = _images(rng, *size)
    _check_loss(image, target, lam, grad_tolerance=2e-5)


def test_loss_reports_the_mse_psnr_measures(rng):
    # The image beyond [0, 1] on purpose: the MSE is of the image clamped, as PSNR's.
    image = rng.uniform(-0.3, 1.3, (31, 45, 3)).astype(np.float32)
    target = rng.uniform(0, 1, image.shape).astype(np.float32)
    want = np.mean((np.clip(np.float64(image), 0, 1) - target) ** 2)
    for need_grad in (True, False):
        got = kernels.l1_ssim_loss(image, target, need_grad=need_grad, threads=2)
        assert abs(got.mse - want) <= 1e-12 * want
    assert kernels.psnr_of_mse(got.mse) == pytest.approx(-10 * np.log10(want), abs=1e-9)
    assert kernels.psnr_of_mse(0.0) == float("inf")


@pytest.mark.parametrize("size", SIZES)
@pytest.mark.parametrize("level", [0.02, 0.5, 0.98])
def test_loss_on_flat_images_matches_reference(rng, size, level):
    # The float32 worst case: variances (1e-6) far below C2, so s1 = e11 - mu1^2 is all
    # cancellation (module docstring).
    image = (level + rng.normal(0, 1e-3, (*size, 3))).astype(np.float32)
    target = (level + rng.normal(0, 1e-3, (*size, 3))).astype(np.float32)
    for lam in (0.2, 1.0):
        _check_loss(image, target, lam, grad_tolerance=5e-4)


def _check_loss(image, target, lam, *, grad_tolerance):
    got = kernels.l1_ssim_loss(image, target, lambda_dssim=lam)
    loss, l1, ssim, grad = rb.l1_ssim_loss(image, target, lam)
    assert got.l1 == pytest.approx(l1, rel=1e-10)
    assert got.ssim == pytest.approx(ssim, abs=1e-5)
    assert got.loss == pytest.approx((1 - lam) * got.l1 + lam * (1 - got.ssim), rel=1e-12, abs=1e-15)
    assert got.loss == pytest.approx(loss, rel=1e-10, abs=lam * 1e-5)
    assert got.grad.dtype == np.float32 and got.grad.shape == image.shape
    err = np.abs(got.grad - grad)
    assert np.all(err <= grad_tolerance * np.abs(grad).max()), err.max() / np.abs(grad).max()


def test_loss_gradient_matches_finite_differences_of_reference(rng):
    # End to end: native gradient against central differences of the float64 loss.
    image, target = _images(rng, 11, 14)
    got = kernels.l1_ssim_loss(image, target, lambda_dssim=0.2)
    base = image.astype(np.float64)
    h = 1e-7
    for index in zip(*(rng.integers(0, n, 30) for n in image.shape)):
        up, down = base.copy(), base.copy()
        up[index] += h
        down[index] -= h
        fd = (rb.l1_ssim_loss(up, target)[0] - rb.l1_ssim_loss(down, target)[0]) / (2 * h)
        assert abs(got.grad[index] - fd) <= 1e-3 * abs(fd) + 1e-9, (index, got.grad[index], fd)


def test_identical_images():
    image = np.random.default_rng(0).uniform(0, 1, (12, 10, 3)).astype(np.float32)
    got = kernels.l1_ssim_loss(image, image.copy())
    # Float32 (module docstring): S = 1 up to rounding of its numerator against its denominator.
    assert got.loss == pytest.approx(0, abs=1e-8) and got.ssim == pytest.approx(1, abs=1e-7)
    assert np.abs(got.grad).max() < 1e-7  # both terms at their minimum


def test_loss_identical_for_any_thread_count_and_reusable_output(rng):
    image, target = _images(rng, 150, 200)
    first = kernels.l1_ssim_loss(image, target, threads=1)
    out = np.full(image.shape, np.nan, np.float32)
    for threads in (2, 3, 0):
        other = kernels.l1_ssim_loss(image, target, threads=threads, out_grad=out)
        assert other.grad is out
        assert (other.loss, other.l1, other.ssim) == (first.loss, first.l1, first.ssim)
        assert np.array_equal(other.grad, first.grad)
    no_grad = kernels.l1_ssim_loss(image, target, need_grad=False)
    assert no_grad.grad is None and no_grad.loss == first.loss


def test_loss_rejects_bad_input(rng):
    image, target = _images(rng, 8, 9)
    with pytest.raises(ValueError, match="shape"):
        kernels.l1_ssim_loss(image[..., :2], target[..., :2])
    with pytest.raises(ValueError, match="differs"):
        kernels.l1_ssim_loss(image, target[:-1])
    with pytest.raises(ValueError, match="lambda"):
        kernels.l1_ssim_loss(image, target, lambda_dssim=1.5)
    bad = image.copy()
    bad[1, 2, 0] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        kernels.l1_ssim_loss(bad, target)
    with pytest.raises(ValueError, match="size"):
        kernels.l1_ssim_loss(np.zeros((0, 4, 3), np.float32), np.zeros((0, 4, 3), np.float32))
    import splatcore
    for args, error, keyword in [
        ((image, target, 0.2, 1, np.zeros((8, 9, 3))), TypeError, "float32"),
        ((image, target, 0.2, 1, np.zeros((9, 8, 3), np.float32)), ValueError, "shape"),
        ((image.astype(np.float64), target, 0.2, 1, None), TypeError, "float32"),
        ((image, target, float("nan"), 1, None), ValueError, "lambda"),
        ((image, target, 0.2, -1, None), ValueError, "threads"),
    ]:
        with pytest.raises(error, match=keyword):
            splatcore.l1_ssim(*args)


# ---------------------------------------------------------------- Adam


def test_adam_matches_reference_over_steps(rng):
    shape = (1000, 3)
    param = rng.normal(size=shape).astype(np.float32)
    m, v = np.zeros(shape, np.float32), np.zeros(shape, np.float32)
    for step in range(1, 8):
        grad = (rng.normal(size=shape) * rng.choice([1e-8, 1e-3, 1.0, 1e3], size=shape)).astype(np.float32)
        grad[::7] = 0  # not seen this step: moments decay, the parameter still moves
        lr = 10.0 ** rng.uniform(-5, -1)
        before = [a.astype(np.float64) for a in (param, m, v)]
        kernels.adam_step(param, grad, m, v, lr=lr, step=step)
        want_p, want_m, want_v = rb.adam(before[0], grad, before[1], before[2], lr=lr, step=step)
        # Moments: float32 rounding of m + 0.1 (g - m), which can cancel: relative to its terms.
        assert np.all(np.abs(m - want_m) <= 1e-6 * (np.abs(before[1]) + np.abs(grad)))
        assert np.all(np.abs(v - want_v) <= 1e-6 * np.abs(want_v))
        # The update, given the moments the kernel computed: 1e-5 relative.
        update = lr / (1 - 0.9 ** step) * m / (np.sqrt(v.astype(np.float64)) / np.sqrt(1 - 0.999 ** step) + 1e-15)
        assert np.all(np.abs(param - (before[0] - update)) <= 1e-5 * np.abs(update) + 1e-7 * np.abs(before[0]))
        assert np.abs(want_p - before[0]).max() <= 3.2 * lr  # Adam's step is bounded by ~lr
    assert np.isfinite(param).all()


def test_adam_zero_gradients_and_threads(rng):
    n = 300_001
    param = rng.normal(size=n).astype(np.float32)
    results = []
    for threads in (1, 2, 3):
        p, m, v = param.copy(), np.zeros(n, np.float32), np.zeros(n, np.float32)
        grad = rng.normal(size=n).astype(np.float32) if not results else results[0][3]
        grad[:1000] = 0
        kernels.adam_step(p, grad, m, v, lr=0.01, step=1, threads=threads)
        kernels.adam_step(p, np.zeros(n, np.float32), m, v, lr=0.01, step=2, threads=threads)
        assert np.isfinite(p).all() and np.array_equal(p[:1000], param[:1000])  # 0/(0+eps) = 0
        results.append((p, m, v, grad))
    for other in results[1:]:
        for a, b in zip(results[0][:3], other[:3]):
            assert np.array_equal(a, b)


def test_adam_rejects_bad_input(rng):
    p = np.zeros((10, 3), np.float32)
    g, m, v = p.copy(), p.copy(), p.copy()
    read_only = p.copy()
    read_only.flags.writeable = False
    bad_grad = g.copy()
    bad_grad[3, 1] = np.inf
    cases = [
        (dict(grad=np.zeros((10, 4), np.float32)), ValueError, "shape"),
        (dict(exp_avg=np.zeros(30, np.float32)), ValueError, "shape"),
        (dict(param=p.astype(np.float64)), TypeError, "float32"),
        (dict(exp_avg_sq=np.zeros((10, 3))), TypeError, "float32"),
        (dict(param=read_only), ValueError, "writable"),
        (dict(param=np.zeros((3, 10), np.float32).T), ValueError, "contiguous"),
        (dict(grad=bad_grad), ValueError, "non-finite"),
        (dict(step=0), ValueError, "step"),
        (dict(lr=-1.0), ValueError, "lr"),
        (dict(lr=float("nan")), ValueError, "lr"),
        (dict(beta1=1.0), ValueError, "beta"),
        (dict(eps=0.0), ValueError, "eps"),
        (dict(threads=-1), ValueError, "threads"),
        (dict(param=[0.0, 1.0]), TypeError, "array"),
    ]
    for change, error, keyword in cases:
        args = dict(param=p, grad=g, exp_avg=m, exp_avg_sq=v) | change
        kwargs = {k: args.pop(k) for k in ("step", "lr", "beta1", "eps", "threads") if k in args}
        kwargs = dict(lr=0.1, step=1) | kwargs
        with pytest.raises(error, match=keyword):
            kernels.adam_step(args["param"], args["grad"], args["exp_avg"], args["exp_avg_sq"], **kwargs)
    assert not p.any()  # nothing was touched by a refused call


def _adam_reference_rows(param, grad, m, v, *, lr, step, rows, lead=0, lead_lr=None):
    """The float64 twin of a masked, two-rate step: rb.adam on the selected rows only (the rest
    unchanged), the first `lead` values of each row at lead_lr."""
    want = [a.astype(np.float64) for a in (param, m, v)]
    flat = lambda a: a.reshape(len(a), -1)  # noqa: E731
    for r in np.flatnonzero(rows):
        for cols, rate in ((slice(0, lead), lead_lr), (slice(lead, None), lr)):
            p, mm, vv = rb.adam(flat(param)[r, cols], flat(grad)[r, cols], flat(m)[r, cols],
                                flat(v)[r, cols], lr=rate, step=step)
            flat(want[0])[r, cols], flat(want[1])[r, cols], flat(want[2])[r, cols] = p, mm, vv
    return want


@pytest.mark.parametrize("shape, lead", [((500, 3), 0), ((300, 16, 3), 3), ((257,), 0), ((40, 4, 3), 12)])
def test_sparse_adam_matches_reference_and_leaves_unselected_rows(rng, shape, lead):
    param = rng.normal(size=shape).astype(np.float32)
    m, v = np.zeros(shape, np.float32), np.zeros(shape, np.float32)
    for step in range(1, 6):
        grad = rng.normal(size=shape).astype(np.float32)
        rows = rng.uniform(size=shape[0]) < 0.6
        rows[:3] = [True, False, True]  # runs of both kinds at a chunk's start
        lr, lead_lr = 10.0 ** rng.uniform(-4, -2), 10.0 ** rng.uniform(-4, -2)
        before = [a.copy() for a in (param, m, v)]
        want_p, want_m, want_v = _adam_reference_rows(param, grad, m, v, lr=lr, step=step,
                                                      rows=rows, lead=lead, lead_lr=lead_lr)
        kernels.adam_step(param, grad, m, v, lr=lr, step=step, rows=rows, lead=lead, lead_lr=lead_lr)
        for got, old in zip((param, m, v), before):  # not selected: bit for bit as before
            assert np.array_equal(got[~rows], old[~rows])
        # Selected rows: the tolerances of test_adam_matches_reference_over_steps, the update
        # judged given the moments the kernel computed (m can cancel: its rounding is its own).
        assert np.all(np.abs(m - want_m) <= 1e-6 * (np.abs(before[1]) + np.abs(grad)))
        assert np.all(np.abs(v - want_v) <= 1e-6 * np.abs(want_v) + 1e-30)
        rate = np.full(param.reshape(len(param), -1).shape[1], lr)
        rate[:lead] = lead_lr
        update = (rate * m.reshape(len(m), -1)).reshape(shape) / (1 - 0.9 ** step) / (
            np.sqrt(v.astype(np.float64)) / np.sqrt(1 - 0.999 ** step) + 1e-15)
        update[~rows] = 0
        assert np.all(np.abs(param - (before[0] - update)) <= 1e-5 * np.abs(update) + 1e-7 * np.abs(before[0]))
        assert np.allclose(want_p, before[0] - update, rtol=0, atol=3.2 * max(lr, lead_lr))


def test_sparse_adam_with_every_row_is_dense_adam_and_thread_independent(rng):
    shape = (70_001, 16, 3)  # several chunks per thread
    base = [rng.normal(size=shape).astype(np.float32) for _ in range(3)]
    grad = rng.normal(size=shape).astype(np.float32)
    base[2] = np.abs(base[2])
    dense = [a.copy() for a in base]
    kernels.adam_step(*dense[:1], grad, *dense[1:], lr=1e-3, step=3, threads=1)
    rows = rng.uniform(size=shape[0]) < 0.5
    results = []
    for threads in (1, 2, 3):
        everything = [a.copy() for a in base]
        kernels.adam_step(everything[0], grad, everything[1], everything[2], lr=1e-3, step=3,
                     rows=np.ones(shape[0], bool), threads=threads)
        assert all(np.array_equal(a, b) for a, b in zip(everything, dense))
        some = [a.copy() for a in base]
        kernels.adam_step(some[0], grad, some[1], some[2], lr=1e-3, step=3, rows=rows, lead=3,
                     lead_lr=2e-3, threads=threads)
        results.append(some)
    for other in results[1:]:
        assert all(np.array_equal(a, b) for a, b in zip(results[0], other))


def test_sparse_adam_rejects_bad_rows_and_lead(rng):
    p = np.zeros((10, 3), np.float32)
    g, m, v = p.copy(), p.copy(), p.copy()
    for kwargs, error, keyword in [
        (dict(rows=np.ones(9, bool)), ValueError, "shape"),
        (dict(rows=np.ones(10, np.int64)), TypeError, "uint8"),
        (dict(lead=4), ValueError, "lead"),
        (dict(used=4), ValueError, "used"),
        (dict(used=1, lead=2), ValueError, "lead"),
        (dict(lead=-1), ValueError, "lead"),
        (dict(lead=1, lead_lr=float("inf")), ValueError, "lead_lr"),
    ]:
        with pytest.raises(error, match=keyword):
            kernels.adam_step(p, g, m, v, lr=0.1, step=1, **kwargs)
    assert not p.any()


def test_adam_used_values_update_only_a_row_prefix(rng):
    shape = (300, 16, 3)
    param, grad = rng.normal(size=shape).astype(np.float32), rng.normal(size=shape).astype(np.float32)
    m, v = rng.normal(size=shape).astype(np.float32), np.abs(rng.normal(size=shape)).astype(np.float32)
    rows = rng.uniform(size=shape[0]) < 0.6
    full = [a.copy() for a in (param, m, v)]
    kernels.adam_step(full[0], grad, full[1], full[2], lr=1e-3, step=4, rows=rows, lead=3, lead_lr=1e-2)
    part = [a.copy() for a in (param, m, v)]
    kernels.adam_step(part[0], grad, part[1], part[2], lr=1e-3, step=4, rows=rows, lead=3, lead_lr=1e-2,
                 used=12)
    for got, want, old in zip(part, full, (param, m, v)):
        assert np.array_equal(got[:, :4], want[:, :4])  # the first 12 values: the full update
        assert np.array_equal(got[:, 4:], old[:, 4:])  # the rest: untouched
    # Values with zero gradient and zero moments: the full update leaves them as they are too.
    grad[:, 4:] = 0.0
    m[:, 4:] = 0.0
    v[:, 4:] = 0.0
    kernels.adam_step(param, grad, m, v, lr=1e-3, step=4, rows=rows)
    assert np.array_equal(param[:, 4:], part[0][:, 4:]) and not m[:, 4:].any() and not v[:, 4:].any()
    grad[0, 5, 1] = np.nan  # refused, even where the update would not read it
    before = param.copy()
    with pytest.raises(ValueError, match="non-finite"):
        kernels.adam_step(param, grad, m, v, lr=1e-3, step=5, used=12)
    assert np.array_equal(param, before)


def test_parameters_adam_skips_sh_bands_never_rendered(rng):
    from addon.core.train.optimizer import GaussianParameters
    from tests.scenes import random_gaussians

    g = random_gaussians(rng, 60, 3)
    lrs = {"means": 1e-3, "log_scales": 2e-3, "quats": 3e-3, "opacity_logits": 4e-3,
           "sh_dc": 2.5e-3, "sh_rest": 1.25e-4}
    skipping, full = GaussianParameters(g), GaussianParameters(g)
    assert skipping.sh_moved == 0
    for step, degree in enumerate([0, 0, 1, 1, 2, 1, 3], start=1):
        grads = kernels.Gradients.zeros_like(g)
        for array in grads.arrays().values():
            array[:] = rng.normal(size=array.shape)
        grads.sh[:, (degree + 1) ** 2:] = 0.0  # as the backward leaves bands not rendered
        rows = rng.uniform(size=60) < 0.7
        skipping.adam_step(grads, lrs, step, rows=rows, sh_coeffs=(degree + 1) ** 2)
        full.adam_step(grads, lrs, step, rows=rows)
        assert skipping.sh_moved == max((d + 1) ** 2 for d in [0, 0, 1, 1, 2, 1, 3][:step])
        for name in skipping.params:
            assert np.array_equal(skipping.params[name], full.params[name])
            assert all(np.array_equal(a, b) for a, b in zip(skipping.moments[name], full.moments[name]))
    restored = GaussianParameters.from_state_arrays(skipping.state_arrays())
    assert restored.sh_moved == 16
    fresh = GaussianParameters(g)
    fresh.moments["sh"][1][5, 6] = 1.0
    assert GaussianParameters.from_state_arrays(fresh.state_arrays()).sh_moved == 7


def test_parameters_adam_step_over_visible_rows(rng):
    from addon.core.train.optimizer import GaussianParameters
    from tests.scenes import random_gaussians

    g = random_gaussians(rng, 50, 2)
    lrs = {"means": 1e-3, "log_scales": 2e-3, "quats": 3e-3, "opacity_logits": 4e-3,
           "sh_dc": 2.5e-3, "sh_rest": 1.25e-4}
    dense, sparse = GaussianParameters(g), GaussianParameters(g)
    rows = rng.uniform(size=50) < 0.5
    for step in range(1, 4):
        grads = kernels.Gradients.zeros_like(g)
        for array in grads.arrays().values():
            array[:] = rng.normal(size=array.shape)
        before = {k: (a.copy(), dense.moments[k][0].copy()) for k, a in sparse.params.items()}
        dense.adam_step(grads, lrs, step)
        sparse.adam_step(grads, lrs, step, rows=rows)
        for name, array in sparse.params.items():
            assert np.array_equal(array[~rows], before[name][0][~rows])
            assert not sparse.moments[name][0][~rows].any()  # never selected, never moved
            if step == 1:  # from equal states, the selected rows get the dense update
                assert np.array_equal(array[rows], dense.params[name][rows])


def _noise_inputs(rng, n):
    means = rng.normal(0, 2, (n, 3)).astype(np.float32)
    log_scales = rng.normal(-2, 1, (n, 3)).astype(np.float32)
    quats = (rng.normal(size=(n, 4)) * rng.uniform(0.1, 3, (n, 1))).astype(np.float32)
    quats[0] = 0.0  # a zero quaternion: identity
    logits = rng.normal(-4, 3, n).astype(np.float32)  # gates from 0 to ~1
    return means, log_scales, quats, logits, rng.standard_normal((n, 3))


def test_position_noise_matches_reference(rng):
    means, log_scales, quats, logits, noise = _noise_inputs(rng, 3000)
    want = rb.position_noise(means, log_scales, quats, logits, noise, 0.3)
    got = means.copy()
    kernels.position_noise(got, log_scales, quats, logits, noise, 0.3)
    # Two float32 roundings: of the step, and of the sum.
    ulps = np.spacing(np.abs(np.float32(want))) + np.spacing(np.abs(np.float32(want - means)))
    assert (np.abs(got - want) <= ulps).all()
    moved = (got != means).any(1)
    assert 100 < moved.sum() < 2900  # opaque ones stay, transparent ones move
    o = 1 / (1 + np.exp(-np.float64(logits)))
    assert not moved[o > 0.3].any()


def test_position_noise_identical_for_any_thread_count(rng):
    means, log_scales, quats, logits, noise = _noise_inputs(rng, 20_000)
    results = []
    for threads in (1, 2, 5):
        got = means.copy()
        kernels.position_noise(got, log_scales, quats, logits, noise, 0.1, threads=threads)
        results.append(got)
    assert all(np.array_equal(results[0], r) for r in results[1:])


def test_position_noise_rejects_bad_input(rng):
    means, log_scales, quats, logits, noise = _noise_inputs(rng, 10)
    for args, error, keyword in [
        ((means.astype(np.float64), log_scales, quats, logits, noise, 1.0), TypeError, "means"),
        ((means, log_scales[:5], quats, logits, noise, 1.0), ValueError, "log_scales"),
        ((means, log_scales, quats[:, :3], logits, noise, 1.0), ValueError, "quats"),
        ((means, log_scales, quats, logits, noise[:4], 1.0), ValueError, "noise"),
        ((means, log_scales, quats, logits, noise, float("nan")), ValueError, "scale"),
    ]:
        before = args[0].copy()
        with pytest.raises(error, match=keyword):
            kernels.position_noise(*args)
        assert np.array_equal(args[0], before)
    frozen = means.copy()
    frozen.flags.writeable = False
    with pytest.raises(ValueError, match="writable"):
        kernels.position_noise(frozen, log_scales, quats, logits, noise, 1.0)
