"""Training kernels over the native module: the training forward, the backward pass, the 3DGS
photometric loss and Adam. Blender-free; numpy arrays in and out.

One training step, as a loop in `addon/core` would run it (no large array is copied; the
gradient and moment arrays are allocated once per Gaussian count and reused):

    result, state = render_train(gaussians, camera, background=bg)
    loss = l1_ssim_loss(result.rgb, target, lambda_dssim=0.2, out_grad=d_rgb)
    grads = backward(state, gaussians, loss.grad, out=grads)
    for name, param in gaussians.arrays().items():
        adam_step(param, grads.arrays()[name], m[name], v[name], lr=lrs[name], step=t)

Semantics (docs/conventions.md, "Rendering semantics"; the gradient conventions at the piecewise
boundaries are listed in native/include/splatcore.h, "training"):
- `render_train` renders exactly what `addon.core.render.renderer.render` renders without a mesh layer
  (bit-identical images) and keeps, in a `TrainState`, what the backward needs: the projected
  Gaussians in depth order, their tile lists, and per pixel the final transmittance and
  n_contrib (the reference CUDA rasterizer's per-pixel record; no per-pixel lists).
- `backward` returns dL/d(parameter) for every Gaussian given dL/d(rgb), dL/d(alpha) and
  dL/d(depth) of that render; Gaussians that were not drawn get 0. The Gaussians passed must be
  the same, unchanged: run the optimizer step after the backward pass (a changed Gaussian that
  was drawn is detected and refused).
- Results are identical for any thread count.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .. import native
from ..cameras import Camera
from ..gaussians import Gaussians
from ..render.renderer import RenderResult

# Adam as 3DGS configures it (torch.optim.Adam(eps=1e-15)).
ADAM_BETA1 = 0.9
ADAM_BETA2 = 0.999
ADAM_EPS = 1e-15


@dataclass
class TrainState:
    """What `backward` needs from one `render_train` call. Holds native memory
    (O(Gaussians + tile pairs)); freed when the object is.

    final_t (H, W) float32: transmittance left after the Gaussians (before the background).
    n_contrib (H, W) int32: tile-list entries up to and including the last Gaussian added at
        the pixel (0 where none was), as the reference CUDA rasterizer's n_contrib.
    visible (N,) bool: the Gaussians drawn (projected, with a footprint reaching the image):
        3DGS's `radii > 0` visibility filter for densification statistics.
    """

    handle: object = field(repr=False)  # the native state (a capsule)
    width: int
    height: int
    count: int
    sh_coeffs: int
    sh_degree: int
    antialiased: bool
    drawn: int
    tile_pairs: int
    final_t: np.ndarray = field(repr=False)
    n_contrib: np.ndarray = field(repr=False)
    visible: np.ndarray = field(repr=False)


@dataclass
class Gradients:
    """dL/d(each Gaussian parameter), in the layout of `Gaussians` (float32), plus the
    screen-space statistics 3DGS densification uses.

    means (N, 3), log_scales (N, 3), quats (N, 4), opacity_logits (N,), sh (N, K, 3): gradients
        of the parameters; SH bands above the rendered degree are 0; rows of Gaussians that were
        not drawn are 0; a zero quaternion's gradient is 0.
    xy (N, 2): dL/d(projected mean), in pixels, summed over all pixels (the compositor's part
        only, as 3DGS's `viewspace_points.grad`, which is this times (W/2, H/2): NDC units).
    xy_abs (N, 2): the sum over pixels of |each pixel's dL/dx| and |dL/dy| (gsplat's "absgrad").
    stats: timings (ms) and counts of the native call; `flushed` counts non-finite values
        written as 0 (only in extreme overflow; expected 0).
    """

    means: np.ndarray
    log_scales: np.ndarray
    quats: np.ndarray
    opacity_logits: np.ndarray
    sh: np.ndarray
    xy: np.ndarray
    xy_abs: np.ndarray
    stats: dict = field(default_factory=dict)

    @classmethod
    def zeros(cls, count: int, sh_coeffs: int) -> "Gradients":
        f = np.float32
        return cls(np.zeros((count, 3), f), np.zeros((count, 3), f), np.zeros((count, 4), f),
                   np.zeros(count, f), np.zeros((count, sh_coeffs, 3), f),
                   np.zeros((count, 2), f), np.zeros((count, 2), f))

    @classmethod
    def zeros_like(cls, gaussians: Gaussians) -> "Gradients":
        return cls.zeros(len(gaussians), gaussians.sh.shape[1])

    def arrays(self) -> dict[str, np.ndarray]:
        """The parameter gradients, keyed like `Gaussians.arrays()`."""
        return {"means": self.means, "log_scales": self.log_scales, "quats": self.quats,
                "opacity_logits": self.opacity_logits, "sh": self.sh}

    def fits(self, count: int, sh_coeffs: int) -> bool:
        """Whether every array has the shape for `count` Gaussians of `sh_coeffs` coefficients."""
        want = {"means": (count, 3), "log_scales": (count, 3), "quats": (count, 4),
                "opacity_logits": (count,), "sh": (count, sh_coeffs, 3), "xy": (count, 2),
                "xy_abs": (count, 2)}
        return all(getattr(self, k).shape == s for k, s in want.items())


@dataclass
class LossResult:
    """loss = (1 - lambda) l1 + lambda (1 - ssim); grad = dloss/d(image) (H, W, 3) or None;
    mse: the mean squared error of the image clamped to [0, 1] (`psnr_of_mse` gives the PSNR)."""

    loss: float
    l1: float
    ssim: float
    grad: np.ndarray | None
    mse: float = float("nan")


def render_train(gaussians: Gaussians, camera: Camera, *, background: np.ndarray | None = None,
                 antialiased: bool = False, near: float = 0.01, sh_degree: int | None = None,
                 threads: int = 0, out: RenderResult | None = None,
                 exhaustive: bool = False) -> tuple[RenderResult, TrainState]:
    """The training forward: `render()` without a mesh layer, plus the state `backward` needs.

    background: RGB (3,) behind the Gaussians (part of `rgb` and of the gradient), or None.
    out: a RenderResult of the right size to render into (its arrays are reused), or None.
    exhaustive: this forward and the `backward` of its state run their slow twins (for tests:
        each Gaussian over its tiles' whole bounding spans, as `render(exhaustive=True)`, and
        the projection backward one Gaussian at a time instead of eight side by side).
    Returns (images, state); the images are bit-identical to `render()`'s.
    """
    _, _, width, height = native.camera_args(camera)
    background = native.background_arg(background)
    if out is None:
        out = RenderResult(np.empty((height, width, 3), np.float32),
                           np.empty((height, width), np.float32),
                           np.empty((height, width), np.float32))
    final_t = np.empty((height, width), np.float32)
    n_contrib = np.empty((height, width), np.int32)
    visible = np.empty(len(gaussians), np.uint8)
    degree = native.resolve_sh_degree(gaussians, sh_degree)
    stats, handle = native.render_train(
        gaussians, camera, background, out.rgb, out.alpha, out.depth, final_t, n_contrib, visible,
        sh_degree=degree, near=near, antialiased=antialiased, threads=threads,
        exhaustive=exhaustive)
    out.stats = dict(stats)
    info = native.train_state_info(handle)
    state = TrainState(handle, width, height, info["count"], info["sh_coeffs"], degree,
                       bool(antialiased), info["drawn"], info["tile_pairs"], final_t, n_contrib,
                       visible.view(bool))
    return out, state


def backward(state: TrainState, gaussians: Gaussians, d_rgb: np.ndarray,
             d_alpha: np.ndarray | None = None, d_depth: np.ndarray | None = None, *,
             threads: int = 0, out: Gradients | None = None) -> Gradients:
    """Gradients of a loss w.r.t. every parameter of `gaussians`, the Gaussians `state` was
    rendered from (unchanged since).

    d_rgb (H, W, 3): dL/d(rgb) of the rendered (premultiplied, background included) image.
    d_alpha (H, W) or None: dL/d(alpha), alpha = 1 - final transmittance.
    d_depth (H, W) or None: dL/d(expected depth) (sum w z / sum w); ignored where the depth is
        inf (nothing drawn). It is ill-conditioned where the coverage sum w is small.
    out: Gradients of the right shapes to overwrite (reused across steps), or None.
    """
    if not isinstance(state, TrainState):
        raise TypeError(f"state must be the TrainState from render_train, got {type(state).__name__}")
    native.gaussian_args(gaussians)  # a TypeError for anything but Gaussians, first
    if len(gaussians) != state.count or gaussians.sh.shape[1] != state.sh_coeffs:
        raise ValueError(f"the Gaussians (N={len(gaussians)}, K={gaussians.sh.shape[1]}) are not "
                         f"those render_train drew (N={state.count}, K={state.sh_coeffs})")
    h, w = state.height, state.width
    d_rgb = native.float_image("d_rgb", d_rgb, (h, w, 3))
    if d_alpha is not None:
        d_alpha = native.float_image("d_alpha", d_alpha, (h, w))
    if d_depth is not None:
        d_depth = native.float_image("d_depth", d_depth, (h, w))
    if out is None:
        out = Gradients.zeros(state.count, state.sh_coeffs)
    elif not isinstance(out, Gradients) or not out.fits(state.count, state.sh_coeffs):
        raise ValueError("out must be Gradients shaped like the Gaussians (Gradients.zeros_like)")
    stats = native.backward(
        state.handle, gaussians, d_rgb, d_alpha, d_depth, out.means, out.log_scales, out.quats,
        out.opacity_logits, out.sh, out.xy, out.xy_abs, threads=threads)
    out.stats = dict(stats)
    return out


def screen_gradient_norm(grads: Gradients, width: int, height: int, *,
                         kind: str = "3dgs") -> np.ndarray:
    """Per-Gaussian screen-space gradient magnitude for densification, (N,) float32.

    kind "3dgs": |(xy_x W/2, xy_y H/2)|, the norm of the reference code's
        `viewspace_points.grad[:, :2]` (NDC units) for one image, so 3DGS's threshold (2e-4 on
        its average over the views that saw the Gaussian) applies unchanged;
    kind "abs": the same scaling of `xy_abs` (gsplat's absgrad=True; its threshold is ~8e-4);
    kind "pixels": |xy| in pixels, unscaled.
    """
    if kind == "pixels":
        return np.linalg.norm(grads.xy, axis=1)
    scale = np.array([width / 2.0, height / 2.0], np.float32)
    if kind == "3dgs":
        return np.linalg.norm(grads.xy * scale, axis=1)
    if kind == "abs":
        return np.linalg.norm(grads.xy_abs * scale, axis=1)
    raise ValueError(f"kind must be '3dgs', 'abs' or 'pixels', got {kind!r}")


def l1_ssim_loss(image: np.ndarray, target: np.ndarray, *, lambda_dssim: float = 0.2,
                 need_grad: bool = True, out_grad: np.ndarray | None = None,
                 threads: int = 0) -> LossResult:
    """The 3DGS photometric loss (1 - lambda) L1 + lambda (1 - SSIM) and its gradient.

    image, target (H, W, 3), values nominally in [0, 1]. L1 is the mean absolute difference;
    SSIM is 3DGS's: 11x11 Gaussian window (sigma 1.5), C1 = 0.01^2, C2 = 0.03^2, per channel,
    zero padding of 5 (conv2d padding = window // 2), averaged over all pixels and channels.
    The gradient (H, W, 3) float32 goes into out_grad when given (reused), else a new array;
    need_grad=False skips it (about half the work).
    """
    image, target = native.rgb_image("image", image), native.rgb_image("target", target)
    if target.shape != image.shape:
        raise ValueError(f"target shape {target.shape} differs from image shape {image.shape}")
    lam = float(lambda_dssim)
    if not 0.0 <= lam <= 1.0:
        raise ValueError(f"lambda_dssim must be in [0, 1], got {lambda_dssim}")
    grad = None
    if need_grad:
        grad = np.empty(image.shape, np.float32) if out_grad is None else out_grad
    loss, l1, ssim, mse = native.l1_ssim(image, target, lam, grad, threads=threads)
    return LossResult(loss, l1, ssim, grad, mse)


def psnr_of_mse(mse: float) -> float:
    """PSNR in dB of a mean squared error of [0, 1] images (inf for 0)."""
    return float("inf") if mse == 0 else -10.0 * math.log10(mse)


def adam_step(param: np.ndarray, grad: np.ndarray, exp_avg: np.ndarray, exp_avg_sq: np.ndarray,
              *, lr: float, step: int, beta1: float = ADAM_BETA1, beta2: float = ADAM_BETA2,
              eps: float = ADAM_EPS, rows: np.ndarray | None = None, lead: int = 0,
              lead_lr: float | None = None, used: int | None = None, threads: int = 0) -> None:
    """One Adam update of `param` in place, with its moments `exp_avg`, `exp_avg_sq` (in place).

    torch.optim.Adam's formula (no weight decay, no amsgrad), in float32:
        m = b1 m + (1 - b1) g;  v = b2 v + (1 - b2) g^2
        param -= lr / (1 - b1^step) * m / (sqrt(v) / sqrt(1 - b2^step) + eps)
    step counts from 1. All four arrays: float32, C-contiguous, one shape (no copies are made:
    a converted copy would not be updated in place, so other dtypes are an error).

    rows: bool or uint8 (param.shape[0],), or None (every row): only the rows along the first
        axis where it is set are updated; the others keep their values and moments exactly
        (gsplat's `visible_adam`: a Gaussian not seen this step neither moves nor decays its
        moments; `step` still counts every step, as there).
    lead, lead_lr: the first `lead` values of each row step at `lead_lr` instead of `lr` (the
        SH DC coefficients of an (N, K, 3) array: lead 3).
    used: only the first `used` values of each row are updated, the rest left as they are
        (None: all). Values whose gradient and moments are all 0 (SH bands never rendered yet)
        would not change anyway: leaving them out only saves the time.
    """
    if rows is not None:
        rows = np.asarray(rows)
        if rows.dtype == np.bool_:
            rows = rows.view(np.uint8)
    native.adam(param, grad, exp_avg, exp_avg_sq, lr=lr, beta1=beta1, beta2=beta2, eps=eps,
                step=step, threads=threads, rows=rows, lead=lead,
                lead_lr=lr if lead_lr is None else lead_lr, used=-1 if used is None else used)


def position_noise(means: np.ndarray, log_scales: np.ndarray, quats: np.ndarray,
                   opacity_logits: np.ndarray, noise: np.ndarray, scale: float, *,
                   threads: int = 0) -> None:
    """3DGS-MCMC's position noise, in place on `means` (float32 (N, 3), C-contiguous):

        o = sigmoid(opacity_logits);  gate = sigmoid(100 ((1 - o) - 0.995))
        means += float32(R diag(exp(log_scales)^2) R^T noise * gate * scale)

    R the rotation of the normalised quaternion (identity for a zero one), noise (N, 3) the
    caller's standard normal draw (float64, so the random stream stays the caller's); in double
    per Gaussian, as the reference's float64 NumPy. Means whose gate is at most 1e-12 (opacity
    above about 0.27: a move below float32 resolution) are left exactly as they are.
    """
    native.position_noise(means, log_scales, quats, opacity_logits,
                          np.ascontiguousarray(noise, np.float64), scale, threads=threads)
