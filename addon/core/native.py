"""The one door to the native module `splatcore`: importing it, and turning Python arguments
(cameras, Gaussians, thread counts, SH degrees, images) into what its functions take, checked
before anything crosses the boundary. `render.py` and `train_kernels.py` call the kernels
through these helpers, as gsplat's `cuda/_wrapper.py` does for its kernels.
"""

from __future__ import annotations

import os

import numpy as np

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
    intrinsics are [fx, fy, cx, cy], then the model's code, far (0: none) and its parameters
    (padded to MAX_MODEL_PARAMS), as splatcore's sc_camera holds them."""
    width, height = int(camera.width), int(camera.height)
    if width <= 0 or height <= 0:
        raise ValueError(f"image size must be positive, got {width}x{height}")
    if width > MAX_SIDE or height > MAX_SIDE or width * height > MAX_PIXELS:
        raise ValueError(f"image size {width}x{height} is too large "
                         f"(at most {MAX_SIDE} a side and {MAX_PIXELS} pixels)")
    viewmat = np.ascontiguousarray(camera.world_to_camera, dtype=np.float64)
    params = list(camera.params) + [0.0] * (MAX_MODEL_PARAMS - len(camera.params))
    far = camera.far if np.isfinite(camera.far) else 0.0
    intrinsics = np.array([camera.fx, camera.fy, camera.cx, camera.cy,
                           MODELS[camera.model][0], far, *params], dtype=np.float64)
    return viewmat, intrinsics, width, height


def gaussian_args(gaussians: Gaussians) -> tuple[np.ndarray, ...]:
    """The five parameter arrays in the order every kernel takes them."""
    if not isinstance(gaussians, Gaussians):
        raise TypeError(f"expected Gaussians, got {type(gaussians).__name__}")
    return (gaussians.means, gaussians.log_scales, gaussians.quats, gaussians.opacity_logits,
            gaussians.sh)


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


def srgb_view(rgba: np.ndarray, out: np.ndarray, decode: bool, zero_non_finite: bool,
              threads: int) -> None:
    """Premultiplied float32 RGBA (H, W, 4), any strides (views of an EXR's planar channels, a
    row-reversed buffer), through the extended sRGB transfer into `out` (`rgba` itself, or not
    overlapping it): scene-linear -> display, or back with `decode` (see `addon.core.colour`).
    With `zero_non_finite`, non-finite results (alpha too) become 0."""
    splatcore().srgb_view(rgba, out, bool(decode), bool(zero_non_finite), thread_count(threads))


def srgb_decode_changed(rgb: np.ndarray, alpha: np.ndarray, mesh: np.ndarray, layer: np.ndarray,
                        threads: int, out: np.ndarray | None = None) -> None:
    """compose's way back to scene-linear, into `out` (default: `layer` itself, the (H, W, 4)
    display layer the composite was made over): the composite (rgb (H, W, 3), alpha (H, W),
    display sRGB) decoded where its colour bits or its alpha (by more than 1e-6) differ from
    `layer`; `mesh`'s scene-linear pixel, bit for bit, elsewhere. All float32; rgb, alpha and
    layer C-contiguous, mesh and out (H, W, 4) with any strides."""
    if out is None:
        splatcore().srgb_decode_changed(rgb, alpha, mesh, layer, thread_count(threads))
    else:
        splatcore().srgb_decode_changed(rgb, alpha, mesh, layer, thread_count(threads), out)
