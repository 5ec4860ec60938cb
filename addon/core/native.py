"""The one door to the native module `splatcore`: importing it, turning Python arguments
(cameras, Gaussians, thread counts, SH degrees, images) into what its functions take, and one
typed function per native entry point (the end of this file), as gsplat's `cuda/_wrapper.py`
does for its kernels. No other module calls `splatcore`: the renderer (`render/renderer.py`,
`render/composite.py`), the training kernels (`train/kernels.py`) and Blender's side
(`blender/sources/gather.py`) call these functions. The native module checks every argument again
(`native/src/module.c`, a table per entry point) and raises TypeError or ValueError.
"""

from __future__ import annotations

import os

import numpy as np

from typing import Any

from .cameras import MAX_MODEL_PARAMS, MODELS, Camera
from .gaussians import Gaussians

# Images beyond these are refused before anything is allocated.
MAX_SIDE = 32768
MAX_PIXELS = 1 << 27


def splatcore():
    """The native module, or an ImportError that says how to build it."""
    try:
        import splatcore as module
    except ImportError as error:  # pragma: no cover - a broken install, not a code path
        raise ImportError(
            "the native module 'splatcore' is not installed; run scripts/bootstrap.sh "
            "(or pip install ./native)") from error
    return module


def camera_args(camera: Camera) -> tuple[np.ndarray, np.ndarray, int, int]:
    """(world-to-camera 4x4 float64, intrinsics float64, width, height), size checked. The
    intrinsics are [fx, fy, cx, cy], then the model's code, far (0: none), the depth of field's
    aperture (0: none) and focus, and the model's parameters (padded to MAX_MODEL_PARAMS), as
    splatcore's sc_camera holds them."""
    width, height = int(camera.width), int(camera.height)
    if width <= 0 or height <= 0:
        raise ValueError(f"image size must be positive, got {width}x{height}")
    if width > MAX_SIDE or height > MAX_SIDE or width * height > MAX_PIXELS:
        raise ValueError(f"image size {width}x{height} is too large "
                         f"(at most {MAX_SIDE} a side and {MAX_PIXELS} pixels)")
    viewmat = np.ascontiguousarray(camera.world_to_camera, dtype=np.float64)
    params = list(camera.params) + [0.0] * (MAX_MODEL_PARAMS - len(camera.params))
    far = camera.far if np.isfinite(camera.far) else 0.0
    aperture, focus = (camera.aperture, camera.focus) if camera.aperture > 0 else (0.0, 1.0)
    intrinsics = np.array([camera.fx, camera.fy, camera.cx, camera.cy, MODELS[camera.model][0],
                           far, aperture, focus, *params], dtype=np.float64)
    return viewmat, intrinsics, width, height


def gaussian_args(gaussians: Gaussians) -> tuple[np.ndarray, ...]:
    """The five parameter arrays in the order every kernel takes them."""
    if not isinstance(gaussians, Gaussians):
        raise TypeError(f"expected Gaussians, got {type(gaussians).__name__}")
    return (gaussians.means, gaussians.log_scales, gaussians.quats, gaussians.opacity_logits,
            gaussians.sh)


def gaussian_arrays(gaussians: Gaussians) -> dict[str, np.ndarray]:
    """The five parameter arrays by the names every kernel takes them by (the field names)."""
    gaussian_args(gaussians)  # a TypeError for anything but Gaussians
    return gaussians.arrays()


def resolve_sh_degree(gaussians: Gaussians, degree: int | None) -> int:
    """The SH degree to evaluate: `degree` (0..3) capped at what the Gaussians hold; None: all."""
    if degree is None:
        return gaussians.degree
    if not 0 <= degree <= 3:
        raise ValueError(f"sh_degree must be 0..3 or None, got {degree}")
    return min(degree, gaussians.degree)


def thread_count(threads: int) -> int:
    """`threads` checked (0 means every core; the kernels resolve it)."""
    if threads < 0:
        raise ValueError(f"threads must be >= 0 (0 = all cores), got {threads}")
    return threads


def cpu_count() -> int:
    """Cores this process may use (what `threads=0` means)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def background_arg(background) -> np.ndarray | None:
    """An RGB triple as float32 (3,), or None (black)."""
    if background is None:
        return None
    array = np.ascontiguousarray(background, dtype=np.float32).reshape(-1)
    if array.shape != (3,):
        raise ValueError(f"background must be an RGB triple, got shape {array.shape}")
    return array


def float_image(name: str, value, shape: tuple[int, ...]) -> np.ndarray:
    """`value` as a C-contiguous float32 array of exactly `shape`."""
    array = np.ascontiguousarray(value, dtype=np.float32)
    if array.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {array.shape}")
    return array


def rgb_image(name: str, value) -> np.ndarray:
    """`value` as a C-contiguous float32 (H, W, 3) array."""
    array = np.ascontiguousarray(value, dtype=np.float32)
    if array.ndim != 3 or array.shape[2] != 3:
        raise ValueError(f"{name} must have shape (H, W, 3), got {array.shape}")
    return array


def frame_args(gaussians: Gaussians, camera: Camera, *, sh_degree: int | None, near: float,
               antialiased: bool, threads: int) -> dict[str, Any]:
    """The arguments project, render, render_train and compose_prepare share, by name: the
    Gaussians, the camera and the options."""
    viewmat, intrinsics, width, height = camera_args(camera)
    return dict(gaussian_arrays(gaussians),
                sh_degree=resolve_sh_degree(gaussians, sh_degree), world_to_camera=viewmat,
                intrinsics=intrinsics, width=width, height=height, near=float(near),
                antialiased=bool(antialiased), threads=thread_count(threads))


# ---------------------------------------------------------------- the native entry points
# One function per function of `splatcore`, in the order of native/src/module.c's method table.
# Every argument is passed by name: the order, the dtypes and the shapes are declared once, in
# native/src/bindings.h (`signature` lists them), and this file holds no copy of them. The
# Gaussians and the camera are converted here (`frame_args`), so a change of what a kernel takes
# of them is made in this file and bindings.h only.


def project(gaussians: Gaussians, camera: Camera, out_xy: np.ndarray, out_conic: np.ndarray,
            out_depth: np.ndarray, out_opacity: np.ndarray, out_rgb: np.ndarray,
            out_valid: np.ndarray, *, sh_degree: int | None, near: float, antialiased: bool,
            threads: int) -> None:
    """Project every Gaussian into `camera` into the out_* float32 arrays (N, 2), (N, 3), (N,),
    (N,), (N, 3) and `out_valid` uint8 (N,) (`renderer.project`)."""
    splatcore().project(
        **frame_args(gaussians, camera, sh_degree=sh_degree, near=near, antialiased=antialiased,
                     threads=threads),
        out_xy=out_xy, out_conic=out_conic, out_depth=out_depth, out_opacity=out_opacity,
        out_rgb=out_rgb, out_valid=out_valid)


def render(gaussians: Gaussians, camera: Camera, background: np.ndarray | None,
           mesh_rgba: np.ndarray | None, mesh_depth: np.ndarray | None, out_rgb: np.ndarray,
           out_alpha: np.ndarray, out_depth: np.ndarray, *, sh_degree: int | None, near: float,
           antialiased: bool, threads: int, exhaustive: bool = False) -> dict[str, float]:
    """Render into out_rgb (H, W, 3), out_alpha and out_depth (H, W), float32, over an optional
    mesh layer (mesh_rgba (H, W, 4) premultiplied, mesh_depth (H, W); both or neither) and
    background (3,) (`renderer.render`). Returns timings (ms) and counts."""
    return dict(splatcore().render(
        **frame_args(gaussians, camera, sh_degree=sh_degree, near=near, antialiased=antialiased,
                     threads=threads),
        background=background, mesh_rgba=mesh_rgba, mesh_depth=mesh_depth, out_rgb=out_rgb,
        out_alpha=out_alpha, out_depth=out_depth, exhaustive=bool(exhaustive)))


def compose_prepare(gaussians: Gaussians, camera: Camera, *, sh_degree: int | None, near: float,
                    antialiased: bool, threads: int) -> tuple[Any, dict[str, float]]:
    """F12's composite, the Gaussians' half: projected, sorted and binned for `camera` (no mesh
    needed yet). Returns (an opaque prepared frame for `compose_srgb`, stats). Releases the
    GIL while it runs."""
    handle, stats = splatcore().compose_prepare(
        **frame_args(gaussians, camera, sh_degree=sh_degree, near=near, antialiased=antialiased,
                     threads=threads))
    return handle, stats


def compose_srgb(prepared: Any, mesh_rgba: np.ndarray, mesh_depth: np.ndarray, out: np.ndarray,
                 out_depth: np.ndarray | None, far: float) -> dict[str, float]:
    """F12's composite, the tile pass: the prepared Gaussians over a scene-linear mesh render
    (mesh_rgba (H, W, 4), mesh_depth (H, W), float32, any strides), composed in display sRGB,
    into `out` (H, W, 4, scene-linear, any strides) and `out_depth` (H, W, or None: no depth);
    tiles no Gaussian reaches keep the mesh's pixels. Returns stats (ms_colour_cpu: the
    conversions' CPU time)."""
    return dict(splatcore().compose_srgb(prepared=prepared, mesh_rgba=mesh_rgba,
                                         mesh_depth=mesh_depth, out=out, out_depth=out_depth,
                                         far=float(far)))


def checksum(buffer) -> tuple[int, int, int, int]:
    """A 256-bit checksum of a C-contiguous buffer's bytes: any change within 193 consecutive
    bits changes it (F12's test whether splat attributes changed)."""
    return splatcore().checksum(buffer)


def sort_keys(keys: np.ndarray, out_order: np.ndarray, *, threads: int) -> int:
    """The renderer's depth sort alone: `out_order` (int32 (N,)) gets the stable ascending order
    of `keys` (float32 (N,); +inf last, -0 before +0, no NaN). Returns how many keys are not
    +inf."""
    return splatcore().sort_keys(keys=keys, threads=thread_count(threads), out_order=out_order)


def release_buffers() -> None:
    """Free the working buffers renders keep for the next frame."""
    splatcore().release_buffers()


def render_train(gaussians: Gaussians, camera: Camera, background: np.ndarray | None,
                 out_rgb: np.ndarray, out_alpha: np.ndarray, out_depth: np.ndarray,
                 out_final_t: np.ndarray | None, out_n_contrib: np.ndarray | None,
                 out_visible: np.ndarray | None, *, sh_degree: int | None, near: float,
                 antialiased: bool, threads: int,
                 exhaustive: bool = False) -> tuple[dict[str, float], Any]:
    """The training forward: `render` without a mesh layer, bit for bit, plus per pixel the
    final transmittance (float32) and n_contrib (int32) (H, W), and per Gaussian whether it was
    drawn (uint8 (N,)), each None to skip. Returns (stats, the opaque state `backward` needs)."""
    return splatcore().render_train(
        **frame_args(gaussians, camera, sh_degree=sh_degree, near=near, antialiased=antialiased,
                     threads=threads),
        background=background, out_rgb=out_rgb, out_alpha=out_alpha, out_depth=out_depth,
        out_final_t=out_final_t, out_n_contrib=out_n_contrib, out_visible=out_visible,
        exhaustive=bool(exhaustive))


def train_state_info(state: Any) -> dict[str, Any]:
    """The image size, Gaussian count, options and counts of a `render_train` state."""
    return splatcore().train_state_info(state)


def backward(state: Any, gaussians: Gaussians, d_rgb: np.ndarray, d_alpha: np.ndarray | None,
             d_depth: np.ndarray | None, out_means: np.ndarray, out_log_scales: np.ndarray,
             out_quats: np.ndarray, out_opacity_logits: np.ndarray, out_sh: np.ndarray,
             out_xy: np.ndarray, out_xy_abs: np.ndarray, *, threads: int) -> dict[str, float]:
    """Gradients of a loss with dL/d(rgb) (H, W, 3), dL/d(alpha) and dL/d(depth) (H, W) or None
    w.r.t. the Gaussians `render_train` drew (the same, unchanged), into the out_* arrays
    (overwritten, shaped like the Gaussians' arrays; out_xy, out_xy_abs (N, 2))."""
    return dict(splatcore().backward(
        state=state, **gaussian_arrays(gaussians), d_rgb=d_rgb,
        d_alpha=d_alpha, d_depth=d_depth, threads=thread_count(threads), out_means=out_means,
        out_log_scales=out_log_scales, out_quats=out_quats, out_opacity_logits=out_opacity_logits,
        out_sh=out_sh, out_xy=out_xy, out_xy_abs=out_xy_abs))


def l1_ssim(image: np.ndarray, target: np.ndarray, lambda_dssim: float,
            out_grad: np.ndarray | None, *, threads: int) -> tuple[float, float, float, float]:
    """(1 - lambda) L1 + lambda (1 - SSIM) of (H, W, 3) float32 images, dL/d(image) into
    `out_grad` unless None. Returns (loss, l1, ssim, mse of the image clamped to [0, 1])."""
    return splatcore().l1_ssim(image=image, target=target, lambda_dssim=float(lambda_dssim),
                               threads=thread_count(threads), out_grad=out_grad)


def adam(param: np.ndarray, grad: np.ndarray, exp_avg: np.ndarray, exp_avg_sq: np.ndarray, *,
         lr: float, beta1: float, beta2: float, eps: float, step: int, threads: int,
         rows: np.ndarray | None, lead: int, lead_lr: float, used: int) -> None:
    """One Adam step in place (torch.optim.Adam's formula) on float32 arrays of one shape; rows
    (uint8 (shape[0],) or None) masks rows; the first `lead` values of a row step at `lead_lr`;
    only the first `used` values of a row are updated (negative: all)."""
    splatcore().adam(param=param, grad=grad, exp_avg=exp_avg, exp_avg_sq=exp_avg_sq,
                     lr=float(lr), beta1=float(beta1), beta2=float(beta2), eps=float(eps),
                     step=int(step), threads=thread_count(threads), rows=rows, lead=int(lead),
                     lead_lr=float(lead_lr), used=int(used))


def position_noise(means: np.ndarray, log_scales: np.ndarray, quats: np.ndarray,
                   opacity_logits: np.ndarray, noise: np.ndarray, scale: float, *,
                   threads: int) -> None:
    """3DGS-MCMC's noise on `means` in place: float32 parameters of N Gaussians, noise (N, 3)
    float64 standard normal."""
    splatcore().position_noise(means=means, log_scales=log_scales, quats=quats,
                               opacity_logits=opacity_logits, noise=noise, scale=float(scale),
                               threads=thread_count(threads))


def neighbours(points: np.ndarray, out: np.ndarray, *, threads: int) -> None:
    """The k nearest other points of each of the float32 (N, 3) `points` into int32 `out`
    (N, k), nearest first, ties to the lower index, -1 where fewer than k others exist."""
    splatcore().neighbours(points=points, threads=thread_count(threads), out=out)


def deformation_jacobians(rest: np.ndarray, deformed: np.ndarray, neighbours: np.ndarray,
                          out_jacobians: np.ndarray, out_rotations: np.ndarray, *,
                          undetermined: float, determined: float, threads: int) -> None:
    """Each point's deformation Jacobian (float64 (N, 3, 3)) fitted to its `neighbours`' rest
    and deformed offsets (float32 (N, 3) each), and its polar rotation (see
    `addon.core.deform.jacobians`)."""
    splatcore().deformation_jacobians(
        rest=rest, deformed=deformed, neighbours=neighbours, undetermined=float(undetermined),
        determined=float(determined), threads=thread_count(threads),
        out_jacobians=out_jacobians, out_rotations=out_rotations)


def deform_shapes(log_scales: np.ndarray, quats: np.ndarray, sh: np.ndarray,
                  jacobians: np.ndarray, rotations: np.ndarray, out_log_scales: np.ndarray,
                  out_quats: np.ndarray, out_sh: np.ndarray, *, threads: int) -> None:
    """Log-scales and quaternions of the covariances J Sigma J^T, SH rotated by each
    Gaussian's orthogonal rotation (float64 (N, 3, 3) each), into the out arrays."""
    splatcore().deform_shapes(
        log_scales=log_scales, quats=quats, sh=sh, jacobians=jacobians, rotations=rotations,
        threads=thread_count(threads), out_log_scales=out_log_scales, out_quats=out_quats,
        out_sh=out_sh)


FIT_FIELDS = 11  # a point's rest half of the fit: FIT_FIELDS + k float64 (SC_FIT_FIELDS)


def deform_rest(rest: np.ndarray, neighbours: np.ndarray, out_fit: np.ndarray, *,
                undetermined: float, determined: float, threads: int) -> None:
    """The half of `deformation_jacobians`' fit that the rest positions (float32 (N, 3)) and
    `neighbours` (int32 (N, k)) alone determine, into float64 `out_fit` (N, FIT_FIELDS + k):
    what `deform_frame` takes, once per rest shape."""
    splatcore().deform_rest(rest=rest, neighbours=neighbours, undetermined=float(undetermined),
                            determined=float(determined), threads=thread_count(threads),
                            out_fit=out_fit)


def deform_frame(rest: np.ndarray, deformed: np.ndarray, neighbours: np.ndarray,
                 order: np.ndarray, fit: np.ndarray, log_scales: np.ndarray, quats: np.ndarray,
                 sh: np.ndarray, out_log_scales: np.ndarray, out_quats: np.ndarray,
                 out_sh: np.ndarray, *, linear: np.ndarray | None,
                 linear_rotation: np.ndarray | None, threads: int) -> None:
    """`deformation_jacobians` then `deform_shapes` in one pass, the maps never stored: rest
    centres (float32 (N, 3)), neighbours (int32 (N, k), as rows) and their `deform_rest` fit
    in the rows of a spatial order, `order` (int32 (N,)) the Gaussian in each row; the
    deformed centres, shapes, SH and outputs by Gaussian (see `addon.core.deform`). `linear`
    and its orthogonal `linear_rotation` (float64 (3, 3) each, or None): a map after the
    deformation."""
    splatcore().deform_frame(
        rest=rest, deformed=deformed, neighbours=neighbours, order=order, fit=fit,
        linear=linear, linear_rotation=linear_rotation, log_scales=log_scales,
        quats=quats, sh=sh, threads=thread_count(threads), out_log_scales=out_log_scales,
        out_quats=out_quats, out_sh=out_sh)


def srgb_premultiplied(rgba: np.ndarray, out: np.ndarray, decode: bool, threads: int) -> None:
    """Premultiplied float32 RGBA (..., 4), C-contiguous, scene-linear -> display sRGB, or back
    with `decode`, into `out` (`rgba` itself, or a C-contiguous array of its shape)."""
    splatcore().srgb_premultiplied(rgba=rgba, out=out, decode=bool(decode),
                                   threads=thread_count(threads))


def srgb_view(rgba: np.ndarray, out: np.ndarray, decode: bool, zero_non_finite: bool,
              threads: int) -> None:
    """Premultiplied float32 RGBA (H, W, 4), any strides (views of an EXR's planar channels, a
    row-reversed buffer), through the extended sRGB transfer into `out` (`rgba` itself, or not
    overlapping it): scene-linear -> display, or back with `decode` (see `addon.core.colour`).
    With `zero_non_finite`, non-finite results (alpha too) become 0."""
    splatcore().srgb_view(rgba=rgba, out=out, decode=bool(decode),
                          zero_non_finite=bool(zero_non_finite), threads=thread_count(threads))


def srgb_decode_changed(rgb: np.ndarray, alpha: np.ndarray, mesh: np.ndarray, layer: np.ndarray,
                        threads: int, out: np.ndarray | None = None) -> None:
    """compose's way back to scene-linear, into `out` (default: `layer` itself, the (H, W, 4)
    display layer the composite was made over): the composite (rgb (H, W, 3), alpha (H, W),
    display sRGB) decoded where its colour bits or its alpha (by more than 1e-6) differ from
    `layer`; `mesh`'s scene-linear pixel, bit for bit, elsewhere. All float32; rgb, alpha and
    layer C-contiguous, mesh and out (H, W, 4) with any strides."""
    splatcore().srgb_decode_changed(rgb=rgb, alpha=alpha, mesh=mesh, layer=layer,
                                    threads=thread_count(threads), out=out)


def viewport_image(rgb: np.ndarray, alpha: np.ndarray, depth: np.ndarray,
                   projection: np.ndarray, out_rgba: np.ndarray, out_depth: np.ndarray, *,
                   threads: int) -> None:
    """A render's rgb (H, W, 3), alpha and planar depth (H, W) into the viewport's
    premultiplied RGBA (H, W, 4) and depth-buffer values (H, W), rows bottom to top;
    `projection` float64 (P22, P23, P32, P33) of the view's OpenGL projection."""
    splatcore().viewport_image(rgb=rgb, alpha=alpha, depth=depth, projection=projection,
                               out_rgba=out_rgba, out_depth=out_depth,
                               threads=thread_count(threads))


def image_memory(bytes: int) -> Any:
    """`bytes` of memory for a render's image, from the buffers frames keep: a writable buffer
    object (view it with NumPy); when the last view is gone the memory is kept for the next
    frame's images (`release_buffers` frees it)."""
    return splatcore().image_memory(bytes=int(bytes))


def photo_rgb(pixels: np.ndarray, out: np.ndarray, *, threads: int) -> None:
    """8-bit photo pixels (H, W, C >= 3), C-contiguous, into `out` float32 (H, W, 3): the first
    three channels times float32(1 / 255)."""
    splatcore().photo_rgb(pixels=pixels, out=out, threads=thread_count(threads))


def composite_microbench(count: int, iterations: int) -> float:
    """Seconds for the compositor's inner loop over one in-cache tile covered by `count`
    Gaussians, `iterations` times (a benchmark's probe)."""
    return splatcore().composite_microbench(count=int(count), iterations=int(iterations))


def native_cpu_count() -> int:
    """Cores the native module may use (its `threads=0`); `cpu_count` is Python's view."""
    return splatcore().cpu_count()


def pool_profile(enable: bool, cpu_clock: bool = False) -> dict[str, float]:
    """The native thread pool's counters since the last call, zeroed (benchmarks): `jobs`
    (parallel sections run), `inside_ms` (their callers' wall time inside them: the rest of a
    native call ran on one thread), `busy_ms` (their threads' working time, summed),
    `offered_ms` (each section's wall time times its threads). Profiles from now on if
    `enable` (process-wide; the stages' stats then fill their `ms_pool_*` fields); with
    `cpu_clock` the stages and sections are timed by the calling thread's CPU clock, not the
    wall clock (for one thread: steady on a busy machine)."""
    return dict(splatcore().pool_profile(enable=bool(enable), cpu_clock=bool(cpu_clock)))


def signature(name: str) -> tuple[tuple[str, str, bool], ...]:
    """The arguments of `splatcore.<name>` in call order, as native/src/bindings.h declares
    them: (name, what it is, whether it may be left out)."""
    return splatcore().signature(name)
