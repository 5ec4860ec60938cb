"""Float64 NumPy reference of the forward renderer: the slow, obviously-correct twin.

This mirrors docs/conventions.md ("Rendering semantics", "Compositing with meshes") and the semantics
stated in `addon/core/render/renderer.py`, step by step, in float64, with no tiles, no bounding boxes
and no cleverness; the native module `splatcore` is held against it. Readability beats speed:
it is vectorised over pixels and loops over the Gaussians in depth order.

`project()` is the per-Gaussian stage (EWA projection, opacity, SH colour);
`render()` composites front to back per pixel, with an optional mesh layer, and also returns
`ambiguous`: the pixels where a float32 implementation may legitimately decide one of the
algorithm's discrete thresholds differently (see `render()`), which tests leave out.

Inputs are whatever the native side gets (float32 arrays, a float64 4x4 world-to-camera);
everything is converted to float64 first.
"""

from __future__ import annotations

import numpy as np

# Real spherical-harmonics constants, as in the reference 3DGS code (forward.cu).
SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
         0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435)

DILATION = 0.3          # low-pass filter added to the 2D covariance (pixels^2)
GUARD_BAND = 0.3        # x/z, y/z clamp margin inside J, as a fraction of tan(half fov)
ALPHA_MIN = 1.0 / 255.0  # a Gaussian with alpha below this is skipped at the pixel
ALPHA_MAX = 0.99        # alpha is clamped to this
T_MIN = 1e-4            # stop before a Gaussian that would take transmittance below this

# Margins of the `ambiguous` mask (see render()). They are relative, and wide enough to cover
# the rounding of a float32 implementation of the same algorithm on ordinary scenes: a float32
# NumPy copy of this file differs from it by at most ~4e-5 relative in o exp(power) and ~2e-5
# in T on the random scenes of tests/scenes.py, and marks 0.1-0.5% of the pixels ambiguous.
AMBIGUOUS_POWER = 1e-4   # |power| below this times the size of its terms: the `power > 0`
                         # skip may flip (only a near-singular conic cancels like that)
AMBIGUOUS_ALPHA = 3e-4   # |o exp(power) - 1/255| below this times 1/255: the alpha skip may flip
AMBIGUOUS_T = 3e-4       # |T (1 - alpha) - 1e-4| below this times 1e-4: the stop may flip


def _f64(value: object) -> np.ndarray:
    return np.asarray(value, dtype=np.float64)


def sh_degree_of(sh: np.ndarray) -> int:
    """SH degree of an (N, K, 3) coefficient array."""
    return {1: 0, 4: 1, 9: 2, 16: 3}[np.shape(sh)[1]]


def quat_to_rotmat(quats: np.ndarray) -> np.ndarray:
    """(N, 4) quaternions w, x, y, z (any length; all zero = identity) -> (N, 3, 3)."""
    q = _f64(quats)
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    identity = np.array([1.0, 0.0, 0.0, 0.0])
    with np.errstate(invalid="ignore", divide="ignore"):
        q = np.where(norm == 0, identity, q / np.where(norm == 0, 1.0, norm))
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def eval_sh(sh: np.ndarray, dirs: np.ndarray, degree: int) -> np.ndarray:
    """SH colour of (N, K, 3) coefficients along unit directions (N, 3), without the +0.5.

    The basis expressions are those of the reference 3DGS `computeColorFromSH`."""
    sh, dirs = _f64(sh), _f64(dirs)
    x, y, z = (dirs[:, i:i + 1] for i in range(3))  # (N, 1), broadcast over RGB
    result = SH_C0 * sh[:, 0]
    if degree > 0:
        result = result - SH_C1 * y * sh[:, 1] + SH_C1 * z * sh[:, 2] - SH_C1 * x * sh[:, 3]
    if degree > 1:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        result = (result
                  + SH_C2[0] * xy * sh[:, 4]
                  + SH_C2[1] * yz * sh[:, 5]
                  + SH_C2[2] * (2 * zz - xx - yy) * sh[:, 6]
                  + SH_C2[3] * xz * sh[:, 7]
                  + SH_C2[4] * (xx - yy) * sh[:, 8])
    if degree > 2:
        result = (result
                  + SH_C3[0] * y * (3 * xx - yy) * sh[:, 9]
                  + SH_C3[1] * xy * z * sh[:, 10]
                  + SH_C3[2] * y * (4 * zz - xx - yy) * sh[:, 11]
                  + SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy) * sh[:, 12]
                  + SH_C3[4] * x * (4 * zz - xx - yy) * sh[:, 13]
                  + SH_C3[5] * z * (xx - yy) * sh[:, 14]
                  + SH_C3[6] * x * (xx - 3 * yy) * sh[:, 15])
    return result


def project(means, log_scales, quats, opacity_logits, sh, viewmat, fx, fy, cx, cy, width,
            height, *, near=0.01, antialiased=False, sh_degree=None) -> dict[str, np.ndarray]:
    """Per-Gaussian screen-space data, as `addon.core.render.renderer.project` documents it.

    Returns xy (N, 2), conic (N, 3) = A, B, C of the inverse dilated 2D covariance, depth (N,)
    view-space z, opacity (N,), rgb (N, 3), valid (N,) bool; rows where valid is False are zero.
    """
    means, log_scales, opacity_logits = _f64(means), _f64(log_scales), _f64(opacity_logits)
    sh, viewmat = _f64(sh), _f64(viewmat)
    fx, fy, cx, cy, near = (float(v) for v in (fx, fy, cx, cy, near))
    degree = sh_degree_of(sh) if sh_degree is None else min(int(sh_degree), sh_degree_of(sh))
    n = len(means)

    with np.errstate(all="ignore"):  # culled rows may divide by zero; they are masked below
        # 3D covariance R diag(exp(s))^2 R^T.
        rot = quat_to_rotmat(quats)
        variances = np.exp(2 * log_scales)
        cov3 = rot @ (variances[:, :, None] * np.swapaxes(rot, 1, 2))

        # Camera space (OpenCV: x right, y down, z forward).
        rv, tv = viewmat[:3, :3], viewmat[:3, 3]
        p_cam = means @ rv.T + tv
        x, y, z = p_cam.T

        # EWA Jacobian, with x/z and y/z clamped to the guard band (only inside J).
        tan_x, tan_y = width / (2 * fx), height / (2 * fy)
        tx = z * np.clip(x / z, -cx / fx - GUARD_BAND * tan_x, (width - cx) / fx + GUARD_BAND * tan_x)
        ty = z * np.clip(y / z, -cy / fy - GUARD_BAND * tan_y, (height - cy) / fy + GUARD_BAND * tan_y)
        jac = np.zeros((n, 2, 3))
        jac[:, 0, 0] = fx / z
        jac[:, 0, 2] = -fx * tx / (z * z)
        jac[:, 1, 1] = fy / z
        jac[:, 1, 2] = -fy * ty / (z * z)
        cov_cam = rv @ cov3 @ rv.T
        cov2 = jac @ cov_cam @ np.swapaxes(jac, 1, 2)
        a, b, c = cov2[:, 0, 0], cov2[:, 0, 1], cov2[:, 1, 1]
        det_raw = a * c - b * b
        a, c = a + DILATION, c + DILATION
        det = a * c - b * b
        conic = np.stack([c / det, -b / det, a / det], axis=1)

        xy = np.stack([fx * x / z + cx, fy * y / z + cy], axis=1)

        opacity = 1.0 / (1.0 + np.exp(-opacity_logits))
        if antialiased:
            opacity = opacity * np.sqrt(np.maximum(0.0, det_raw / det))

        centre = -rv.T @ tv
        dirs = means - centre
        dirs = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
        rgb = np.maximum(eval_sh(sh, dirs, degree) + 0.5, 0.0)

        valid = ((z >= near) & (det > 0) & np.isfinite(det) & np.isfinite(xy).all(1)
                 & np.isfinite(conic).all(1))

    zero = ~valid
    xy[zero], conic[zero], rgb[zero] = 0.0, 0.0, 0.0
    z = np.where(valid, z, 0.0)
    opacity = np.where(valid, opacity, 0.0)
    return {"xy": xy, "conic": conic, "depth": z, "opacity": opacity, "rgb": rgb, "valid": valid}


def render(means, log_scales, quats, opacity_logits, sh, viewmat, fx, fy, cx, cy, width, height,
           *, background=None, mesh_rgba=None, mesh_depth=None, near=0.01, antialiased=False,
           sh_degree=None) -> dict[str, np.ndarray]:
    """Composite front to back per pixel; returns rgb (H, W, 3), alpha, depth, ambiguous (H, W).

    Per pixel (centre at i + 0.5, j + 0.5), the valid Gaussians in ascending depth (ties keep
    index order; the key is the depth rounded to float32, see "Order" below):
    power = -0.5 (A dx^2 + C dy^2) - B dx dy with d = mean - pixel centre; skip if power > 0;
    alpha = min(0.99, o exp(power)); skip if alpha < 1/255; if T (1 - alpha) < 1e-4 stop (this
    Gaussian and all later ones are left out); else add colour, depth and weight alpha T, and
    T *= 1 - alpha. No bounding box: every pixel with alpha >= 1/255 counts.

    Mesh layer (premultiplied mesh_rgba (H, W, 4), planar mesh_depth (H, W)): the Gaussians
    with depth < mesh_depth first, then the mesh (C += T rgb; where its alpha > 0 and depth is
    finite the depth and weight get T a d and T a; T *= 1 - a), then those behind. A pixel that
    stopped still gets the mesh with the T it has left. Then the background (C += T bg); alpha = 1 - T;
    depth = sum(w z) / sum(w), inf where the sum of weights is 0.

    `ambiguous` marks a pixel where, before it stopped, some Gaussian with o exp(power) at least
    about 1/255 was within rounding of a discrete decision:
      - |power| <= AMBIGUOUS_POWER (0.5 (A dx^2 + C dy^2) + |B dx dy|), a cancellation that
        can flip the sign and so the `power > 0` skip (at the mean itself, power = 0 exactly),
      - o exp(power) within AMBIGUOUS_ALPHA (relative) of 1/255 (the alpha skip),
      - T (1 - alpha) within AMBIGUOUS_T (relative) of 1e-4 (the stop).
    The alpha clamp at 0.99 is continuous and never ambiguous.

    Order: the sort key (and the depth compared with mesh_depth) is the float64 depth rounded
    once to float32, the precision of the renderer's depth output and sort key. Depths that
    differ below float32 resolution cannot be ordered by a float32 sort; with this key they tie
    and keep index order on both sides, so the order is never ambiguous (given depths computed
    accurately and rounded once, as the native projection does in double).
    """
    width, height = int(width), int(height)
    proj = project(means, log_scales, quats, opacity_logits, sh, viewmat, fx, fy, cx, cy, width,
                   height, near=near, antialiased=antialiased, sh_degree=sh_degree)
    has_mesh = mesh_rgba is not None
    if has_mesh:
        mesh_rgba, mesh_depth = _f64(mesh_rgba), _f64(mesh_depth)
        assert mesh_rgba.shape == (height, width, 4) and mesh_depth.shape == (height, width)

    px, py = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)  # (H, W)
    transmittance = np.ones((height, width))
    colour = np.zeros((height, width, 3))
    depth_sum = np.zeros((height, width))
    weight_sum = np.zeros((height, width))
    stopped = np.zeros((height, width), bool)
    mesh_pending = np.full((height, width), has_mesh)
    ambiguous = np.zeros((height, width), bool)

    def composite_mesh(where: np.ndarray) -> None:
        t = transmittance[where]
        mesh_a = mesh_rgba[where][:, 3]
        mesh_d = mesh_depth[where]
        colour[where] += t[:, None] * mesh_rgba[where][:, :3]
        counts = (mesh_a > 0) & np.isfinite(mesh_d)
        depth_sum[where] += np.where(counts, t * mesh_a * np.where(counts, mesh_d, 0.0), 0.0)
        weight_sum[where] += np.where(counts, t * mesh_a, 0.0)
        transmittance[where] = t * (1.0 - mesh_a)

    def near_to(value, target, margin):
        return np.isfinite(target) & (np.abs(value - target) <= margin * np.abs(target))

    valid_index = np.flatnonzero(proj["valid"])
    key = proj["depth"].astype(np.float32)
    order = valid_index[np.argsort(key[valid_index], kind="stable")]
    for g in order:
        z = proj["depth"][g]
        if has_mesh:  # the mesh goes before the first Gaussian at or behind its depth
            reached = mesh_pending & (key[g] >= mesh_depth)
            composite_mesh(reached)
            mesh_pending &= ~reached

        (mx, my), (ca, cb, cc) = proj["xy"][g], proj["conic"][g]
        dx, dy = mx - px, my - py
        power = -0.5 * (ca * dx * dx + cc * dy * dy) - cb * dx * dy
        raw_alpha = proj["opacity"][g] * np.exp(power)
        alpha = np.minimum(ALPHA_MAX, raw_alpha)
        test_t = transmittance * (1.0 - alpha)

        active = ~stopped
        reaches = raw_alpha >= ALPHA_MIN * (1 - AMBIGUOUS_ALPHA)  # could count in float32
        take = active & (power <= 0) & (alpha >= ALPHA_MIN)
        stop = take & (test_t < T_MIN)
        add = take & ~stop

        terms = 0.5 * (ca * dx * dx + cc * dy * dy) + np.abs(cb * dx * dy)
        ambiguous |= active & reaches & (np.abs(power) <= AMBIGUOUS_POWER * terms) & (terms > 0)
        ambiguous |= active & (power <= 0) & near_to(raw_alpha, ALPHA_MIN, AMBIGUOUS_ALPHA)
        ambiguous |= take & near_to(test_t, T_MIN, AMBIGUOUS_T)

        weight = np.where(add, alpha * transmittance, 0.0)
        colour += weight[:, :, None] * proj["rgb"][g]
        depth_sum += weight * z
        weight_sum += weight
        transmittance = np.where(add, test_t, transmittance)
        stopped |= stop

    if has_mesh:  # pixels whose Gaussians all lie in front of the mesh (or that stopped)
        composite_mesh(mesh_pending)
    if background is not None:
        colour += transmittance[:, :, None] * _f64(background).reshape(3)
    with np.errstate(invalid="ignore", divide="ignore"):
        depth = np.where(weight_sum > 0, depth_sum / weight_sum, np.inf)
    return {"rgb": colour, "alpha": 1.0 - transmittance, "depth": depth, "ambiguous": ambiguous}


def camera_args(camera) -> tuple:
    """An `addon.core.cameras.Camera` as the positional camera arguments above."""
    return (camera.world_to_camera, camera.fx, camera.fy, camera.cx, camera.cy, camera.width,
            camera.height)


def gaussian_args(gaussians) -> tuple:
    """An `addon.core.gaussians.Gaussians` as the positional Gaussian arguments above."""
    return (gaussians.means, gaussians.log_scales, gaussians.quats, gaussians.opacity_logits,
            gaussians.sh)


def project_scene(gaussians, camera, **options) -> dict[str, np.ndarray]:
    """`project()` on Gaussians and Camera objects."""
    return project(*gaussian_args(gaussians), *camera_args(camera), **options)


def render_scene(gaussians, camera, **options) -> dict[str, np.ndarray]:
    """`render()` on Gaussians and Camera objects."""
    return render(*gaussian_args(gaussians), *camera_args(camera), **options)
