"""Float64 references for the training kernels: gradients of the renderer by central finite
differences of `render` in tests/reference.py, the 3DGS loss (L1 + SSIM) with its analytic gradient,
and Adam. Slow and obviously correct, like tests/reference.py.

Finite differences see the forward exactly as the reference defines it, so they are only
meaningful where it is smooth in every parameter: away from the alpha threshold 1/255, the
0.99 clamp, the 1e-4 transmittance stop, the SH colour clamp at 0, the guard-band clamp inside
J and the near plane. `kinks()` says how close a scene is to any of them; tests draw scenes
until one is clear (`clear_of_kinks`), so a central difference with a relative step of ~1e-6
never straddles a kink and the float32 native forward makes every decision the same way.
"""

from __future__ import annotations

from contextlib import contextmanager
from unittest import mock

import numpy as np

from tests import reference as ref

PARAMS = ("means", "log_scales", "quats", "opacity_logits", "sh")

# Relative distance to a kink below which a scene is not used for finite differences. The
# threshold decisions (alpha skip, stop) also use the reference's `ambiguous` margins, which
# cover float32 rounding in the native forward.
KINK_MARGIN = 1e-4


def _arrays(gaussians) -> dict[str, np.ndarray]:
    return {name: np.array(getattr(gaussians, name), np.float64) for name in PARAMS}


def loss_of_images(out: dict, w_rgb, w_alpha=None, w_depth=None) -> float:
    """The linear test loss L = sum w_rgb rgb + sum w_alpha alpha + sum w_depth depth (depth
    terms only where the depth is finite), whose dL/d(images) are the weights themselves."""
    total = float(np.sum(np.asarray(w_rgb, np.float64) * out["rgb"]))
    if w_alpha is not None:
        total += float(np.sum(np.asarray(w_alpha, np.float64) * out["alpha"]))
    if w_depth is not None:
        finite = np.isfinite(out["depth"])
        total += float(np.sum(np.where(finite, np.asarray(w_depth, np.float64) * np.where(finite, out["depth"], 0), 0)))
    return total


def render_arrays(arrays: dict, camera, **options) -> dict:
    return ref.render(*(arrays[name] for name in PARAMS), *ref.camera_args(camera), **options)


def finite_difference_gradients(gaussians, camera, w_rgb, w_alpha=None, w_depth=None, *,
                                params=PARAMS, rows=None, step=1e-6, **options) -> dict:
    """Central differences of `loss_of_images(reference.render(...))` w.r.t. every element of
    the named parameter arrays (float64, the shapes of the Gaussians' arrays); `rows` limits
    them to some Gaussians (others stay 0). The step is `step * max(1, |p|)`, and for a
    quaternion `step * |q|` (the rotation depends on q / |q| only: a fixed step would be a
    large rotation for a short q)."""
    base = _arrays(gaussians)
    rows = range(len(gaussians)) if rows is None else rows
    grads = {name: np.zeros_like(base[name]) for name in params}
    for name in params:
        array = base[name]
        for i in rows:
            for index in np.ndindex(array.shape[1:]):
                at = (i,) + index
                value = array[at]
                if name == "quats" and np.linalg.norm(array[i]) > 0:
                    h = step * np.linalg.norm(array[i])
                else:
                    h = step * max(1.0, abs(value))
                array[at] = value + h
                up = loss_of_images(render_arrays(base, camera, **options), w_rgb, w_alpha, w_depth)
                array[at] = value - h
                down = loss_of_images(render_arrays(base, camera, **options), w_rgb, w_alpha, w_depth)
                array[at] = value
                grads[name][at] = (up - down) / (2 * h)
    return grads


@contextmanager
def shifted_projection(gaussian: int, dxy):
    """Within the block, reference.render sees Gaussian `gaussian`'s projected mean moved by
    `dxy` pixels (everything else unchanged): the derivative w.r.t. the 2D mean."""
    original = ref.project

    def project(*args, **kwargs):
        out = original(*args, **kwargs)
        out["xy"] = out["xy"].copy()
        out["xy"][gaussian] += dxy
        return out

    with mock.patch.object(ref, "project", project):
        yield


def screen_space_gradients(gaussians, camera, w_rgb, w_alpha=None, w_depth=None, *, step=1e-5,
                           **options) -> tuple[np.ndarray, np.ndarray]:
    """dL/d(projected mean) (N, 2) in pixels by central differences, and the 'absgrad'
    (N, 2): the sum over pixels of |each pixel's dL/dx|, |dL/dy|, from the same differences
    taken per pixel."""
    n = len(gaussians)
    grad, absgrad = np.zeros((n, 2)), np.zeros((n, 2))
    arrays = _arrays(gaussians)
    w_rgb = np.asarray(w_rgb, np.float64)
    for g in range(n):
        for axis in range(2):
            d = np.zeros(2)
            d[axis] = step
            with shifted_projection(g, d):
                up = render_arrays(arrays, camera, **options)
            with shifted_projection(g, -d):
                down = render_arrays(arrays, camera, **options)
            per_pixel = np.sum(w_rgb * (up["rgb"] - down["rgb"]), axis=2)
            if w_alpha is not None:
                per_pixel += w_alpha * (up["alpha"] - down["alpha"])
            if w_depth is not None:
                finite = np.isfinite(up["depth"]) & np.isfinite(down["depth"])
                per_pixel += np.where(finite, w_depth * np.where(finite, up["depth"] - down["depth"], 0), 0)
            per_pixel /= 2 * step
            grad[g, axis] = per_pixel.sum()
            absgrad[g, axis] = np.abs(per_pixel).sum()
    return grad, absgrad


def kinks(gaussians, camera, *, near=0.01, antialiased=False, sh_degree=None,
          background=None) -> dict[str, float]:
    """How close (relatively) the scene is to each kink of the forward; a scene is clear for
    finite differences when every value is above KINK_MARGIN (and `ambiguous_pixels` is 0)."""
    proj = ref.project_scene(gaussians, camera, near=near, antialiased=antialiased,
                             sh_degree=sh_degree)
    out = ref.render_scene(gaussians, camera, near=near, antialiased=antialiased,
                           sh_degree=sh_degree, background=background)
    valid = proj["valid"]
    arrays = _arrays(gaussians)
    viewmat = camera.world_to_camera
    p = arrays["means"] @ viewmat[:3, :3].T + viewmat[:3, 3]
    z = p[:, 2]
    result = {"ambiguous_pixels": float(out["ambiguous"].sum())}
    # Near plane (all Gaussians, valid or not: crossing it changes validity).
    result["near"] = float(np.min(np.abs(z - near) / max(near, 1e-12))) if len(z) else np.inf
    # Guard band: x/z, y/z against the clamp limits.
    fx, fy, cx, cy, w, h = camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height
    lims = [(-cx / fx - ref.GUARD_BAND * w / (2 * fx), (w - cx) / fx + ref.GUARD_BAND * w / (2 * fx)),
            (-cy / fy - ref.GUARD_BAND * h / (2 * fy), (h - cy) / fy + ref.GUARD_BAND * h / (2 * fy))]
    guard = np.inf
    for axis, (lo, hi) in enumerate(lims):
        ratio = p[valid, axis] / z[valid]
        for limit in (lo, hi):
            if len(ratio):
                guard = min(guard, float(np.min(np.abs(ratio - limit) / abs(limit))))
    result["guard_band"] = guard
    # SH colour clamp at 0 (only where the Gaussian is drawn; harmless elsewhere but simple).
    degree = ref.sh_degree_of(arrays["sh"]) if sh_degree is None else sh_degree
    centre = camera.centre
    dirs = arrays["means"] - centre
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    raw = ref.eval_sh(arrays["sh"], dirs, degree) + 0.5
    result["sh_clamp"] = float(np.min(np.abs(raw[valid]))) if valid.any() else np.inf
    # The 0.99 clamp: o exp(power) near 0.99 at any pixel.
    px, py = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    clamp = np.inf
    for g in np.flatnonzero(valid):
        (mx, my), (a, b, c) = proj["xy"][g], proj["conic"][g]
        dx, dy = mx - px, my - py
        power = -0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy
        raw_alpha = proj["opacity"][g] * np.exp(power)
        clamp = min(clamp, float(np.min(np.abs(raw_alpha - ref.ALPHA_MAX) / ref.ALPHA_MAX)))
    result["alpha_clamp"] = clamp
    return result


def clear_of_kinks(report: dict[str, float], margin: float = KINK_MARGIN) -> bool:
    return report["ambiguous_pixels"] == 0 and all(
        v > margin for k, v in report.items() if k != "ambiguous_pixels")


# ---------------------------------------------------------------- loss

SSIM_C1 = 0.01 ** 2
SSIM_C2 = 0.03 ** 2


def gaussian_window(size: int = 11, sigma: float = 1.5) -> np.ndarray:
    """The 2D window of the 3DGS training code (create_window): outer product of a normalised
    1D Gaussian."""
    x = np.arange(size) - size // 2
    g = np.exp(-(x ** 2) / (2 * sigma ** 2))
    g /= g.sum()
    return np.outer(g, g)


def filter2d(image: np.ndarray, window: np.ndarray) -> np.ndarray:
    """torch's conv2d(image, window, padding=size // 2) per channel, written out as a direct 2D
    sum with zero padding: (H, W) -> (H, W)."""
    size = window.shape[0]
    r = size // 2
    h, w = image.shape
    padded = np.zeros((h + 2 * r, w + 2 * r))
    padded[r:r + h, r:r + w] = image
    out = np.zeros((h, w))
    for dy in range(size):
        for dx in range(size):
            out += window[dy, dx] * padded[dy:dy + h, dx:dx + w]
    return out


def ssim_parts(image: np.ndarray, target: np.ndarray):
    """The SSIM map and the pieces its gradient needs, per channel: (H, W, 3) arrays."""
    x, y = np.asarray(image, np.float64), np.asarray(target, np.float64)
    window = gaussian_window()
    f = lambda a: np.stack([filter2d(a[..., c], window) for c in range(3)], -1)  # noqa: E731
    mu1, mu2 = f(x), f(y)
    s1, s2, s12 = f(x * x) - mu1 ** 2, f(y * y) - mu2 ** 2, f(x * y) - mu1 * mu2
    a1, a2 = 2 * mu1 * mu2 + SSIM_C1, 2 * s12 + SSIM_C2
    b1, b2 = mu1 ** 2 + mu2 ** 2 + SSIM_C1, s1 + s2 + SSIM_C2
    s_map = a1 * a2 / (b1 * b2)
    d_mu1 = 2 * mu2 * (a2 - a1) / (b1 * b2) - 2 * mu1 * s_map * (1 / b1 - 1 / b2)
    d_e11 = -s_map / b2
    d_e12 = 2 * a1 / (b1 * b2)
    back = lambda a: f(a)  # noqa: E731  (symmetric window, zero padding: the transpose)
    d_x = back(d_mu1) + 2 * x * back(d_e11) + y * back(d_e12)
    return s_map, d_x


def l1_ssim_loss(image, target, lambda_dssim=0.2) -> tuple[float, float, float, np.ndarray]:
    """(loss, l1, ssim, dloss/dimage) in float64; loss = (1 - lambda) l1 + lambda (1 - ssim)."""
    x, y = np.asarray(image, np.float64), np.asarray(target, np.float64)
    count = x.size
    l1 = float(np.abs(x - y).mean())
    s_map, d_ssim = ssim_parts(x, y)
    ssim = float(s_map.mean())
    loss = (1 - lambda_dssim) * l1 + lambda_dssim * (1 - ssim)
    grad = (1 - lambda_dssim) * np.sign(x - y) / count - lambda_dssim * d_ssim / count
    return loss, l1, ssim, grad


# ---------------------------------------------------------------- Adam


def adam(param, grad, m, v, *, lr, step, beta1=0.9, beta2=0.999, eps=1e-15):
    """One torch.optim.Adam step in float64; returns the new (param, m, v)."""
    param, grad, m, v = (np.asarray(a, np.float64) for a in (param, grad, m, v))
    m = beta1 * m + (1 - beta1) * grad
    v = beta2 * v + (1 - beta2) * grad * grad
    step_size = lr / (1 - beta1 ** step)
    denom = np.sqrt(v) / np.sqrt(1 - beta2 ** step) + eps
    return param - step_size * m / denom, m, v


def position_noise(means, log_scales, quats, opacity_logits, noise, scale) -> np.ndarray:
    """3DGS-MCMC's position noise in float64: the new means (N, 3) float64 (not rounded)."""
    o = 1.0 / (1.0 + np.exp(-np.float64(opacity_logits)))
    gate = 1.0 / (1.0 + np.exp(-100.0 * ((1.0 - o) - 0.995)))
    q = np.float64(quats)
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    q = np.where(norm > 0, q / np.where(norm > 0, norm, 1.0), [1.0, 0.0, 0.0, 0.0])
    w, x, y, z = q.T
    r = np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
                  np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
                  np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)],
                 axis=1)
    covariance = r @ (np.exp(2.0 * np.float64(log_scales))[:, :, None] * np.swapaxes(r, 1, 2))
    step = covariance @ (np.float64(noise) * (gate * scale)[:, None])[:, :, None]
    return np.float64(means) + step[:, :, 0]
