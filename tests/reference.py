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

import math

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
            height, *, near=0.01, antialiased=False, sh_degree=None, model="PINHOLE",
            model_params=(), far=np.inf, aperture=0.0, focus=1.0) -> dict[str, np.ndarray]:
    """Per-Gaussian screen-space data, as `addon.core.render.renderer.project` documents it.

    Returns xy (N, 2), conic (N, 3) = A, B, C of the inverse dilated 2D covariance, depth (N,)
    view-space z, opacity (N,), rgb (N, 3), valid (N,) bool; rows where valid is False are zero.
    Other camera models (`model`, `model_params`, `far`: see `camera_model_project`).
    Depth of field (`aperture` > 0, `focus`): see `depth_of_field`.
    """
    if model != "PINHOLE":
        return camera_model_project(means, log_scales, quats, opacity_logits, sh, viewmat, fx,
                                    fy, cx, cy, width, height, near=near, far=far,
                                    antialiased=antialiased, sh_degree=sh_degree, model=model,
                                    model_params=model_params, aperture=aperture, focus=focus)
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
        conic, mass = depth_of_field(cov2, z, fx, fy, aperture, focus, antialiased, False)

        xy = np.stack([fx * x / z + cx, fy * y / z + cy], axis=1)

        opacity = 1.0 / (1.0 + np.exp(-opacity_logits)) * mass
        det = 1.0 / (conic[:, 0] * conic[:, 2] - conic[:, 1] ** 2)

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
           sh_degree=None, **camera_model) -> dict[str, np.ndarray]:
    """Composite front to back per pixel; returns rgb (H, W, 3), alpha, depth, ambiguous (H, W)
    and weights (rows of `proj`: the N Gaussians, then any seam copies): per Gaussian the sum
    over pixels of its blending weight alpha T.

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
                   height, near=near, antialiased=antialiased, sh_degree=sh_degree, **camera_model)
    if "copies" in proj:  # seam copies come after every Gaussian, as rows N.. of the native
        proj = {k: np.concatenate([proj[k], proj["copies"][k]]) for k in proj["copies"]}
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
    gaussian_weights = np.zeros(len(proj["depth"]))

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
        gaussian_weights[g] = weight.sum()
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
    return {"rgb": colour, "alpha": 1.0 - transmittance, "depth": depth, "ambiguous": ambiguous,
            "weights": gaussian_weights}


def camera_args(camera) -> tuple:
    """An `addon.core.cameras.Camera` as the positional camera arguments above."""
    return (camera.world_to_camera, camera.fx, camera.fy, camera.cx, camera.cy, camera.width,
            camera.height)


def gaussian_args(gaussians) -> tuple:
    """An `addon.core.gaussians.Gaussians` as the positional Gaussian arguments above."""
    return (gaussians.means, gaussians.log_scales, gaussians.quats, gaussians.opacity_logits,
            gaussians.sh)


def camera_model_args(camera) -> dict:
    """A Camera's model, as the keyword arguments of `project()` and `render()`."""
    return dict(model=camera.model, model_params=tuple(camera.params), far=camera.far,
                aperture=camera.aperture, focus=camera.focus)


def depth_of_field(cov2, z, fx, fy, aperture, focus, antialiased, ortho):
    """The conic (N, 3) of 2D covariances `cov2` (N, 2, 2) blurred by a thin lens' circle of
    confusion and dilated, and the opacity factor that keeps each Gaussian's drawn mass.

    A thin lens of radius `aperture` focused at depth `focus` moves a point at depth z by
    f a (1/focus - 1/z) pixels for a lens point a (ORTHO: f a (1 - z/focus)), a uniform over the
    aperture disc, whose covariance is (radius/2)^2 I: so Sigma2 gains
    (aperture |1/focus - 1/z| / 2)^2 diag(fx^2, fy^2). A Gaussian convolved with a Gaussian stays
    one, with its integral: the opacity is multiplied by sqrt(det(before) / det(after)), `before`
    the dilated covariance without the blur (or, antialiased, the raw covariance: the
    Mip-Splatting compensation), `after` the blurred, dilated one. Without blur and antialiasing
    the factor is exactly 1."""
    a, b, c = cov2[:, 0, 0], cov2[:, 0, 1], cov2[:, 1, 1]
    r = aperture * ((1.0 - z / focus) if ortho else (1.0 / focus - 1.0 / z))
    blur = 0.25 * r * r if aperture > 0 else np.zeros_like(z)
    det_raw = a * c - b * b
    before = det_raw if antialiased else (a + DILATION) * (c + DILATION) - b * b
    a, c = a + fx * fx * blur + DILATION, c + fy * fy * blur + DILATION
    det = a * c - b * b
    conic = np.stack([c / det, -b / det, a / det], axis=1)
    mass = np.sqrt(np.maximum(0.0, before / det)) if (antialiased or aperture > 0) else \
        np.ones_like(det)
    return conic, mass


def project_scene(gaussians, camera, **options) -> dict[str, np.ndarray]:
    """`project()` on Gaussians and Camera objects."""
    return project(*gaussian_args(gaussians), *camera_args(camera), **camera_model_args(camera),
                   **options)


def render_scene(gaussians, camera, **options) -> dict[str, np.ndarray]:
    """`render()` on Gaussians and Camera objects."""
    return render(*gaussian_args(gaussians), *camera_args(camera), **camera_model_args(camera),
                  **options)


# ------------------------------------------------------------------ orthographic and panoramas

def _cycles_uv(p: np.ndarray, model: str, params) -> tuple[np.ndarray, np.ndarray]:
    """Cycles' normalised image point (u, v), v up, of camera-space points p (N, 3) (OpenCV frame),
    written from Cycles' own formulas (kernel/camera/projection.h) in Cycles' camera frames, and
    whether the mapping shows each point. Blender turns a panoramic camera so that Cycles'
    camera-space +x is the camera's view axis, +y its left and +z its up (the mirror ball: +x
    right, +y back, +z up)."""
    x, y, z = p.T
    r = np.linalg.norm(p, axis=1)
    if model == "MIRRORBALL":
        d = np.stack([x, -z, -y], 1) / r[:, None]
        d[:, 1] -= 1.0                                            # direction_to_mirrorball
        div = 2.0 * np.sqrt(np.maximum(-0.5 * d[:, 1], 0.0))
        d = d / np.where(div > 0, div, 1.0)[:, None]
        behind = np.arccos(np.clip(z / r, -1, 1)) >= np.pi - 1e-3  # maps onto the whole rim
        return np.stack([0.5 * (d[:, 0] + 1), 0.5 * (d[:, 2] + 1)], 1), ~behind
    d = np.stack([z, -x, -y], 1) / r[:, None]                      # forward, left, up
    if model == "EQUIRECTANGULAR":
        lon_min, lon_max, lat_min, lat_max = params                 # Blender's sync of the range
        rx, ry, rz, rw = lon_min - lon_max, -lon_min, lat_min - lat_max, np.pi / 2 - lat_min
        u = (np.arctan2(d[:, 1], d[:, 0]) - ry) / rx
        v = (np.arccos(np.clip(d[:, 2], -1, 1)) - rw) / rz
        return np.stack([u, v], 1), np.ones(len(p), bool)
    if model == "CENTRAL_CYLINDRICAL":                              # direction_to_central_
        u_min, u_max, v_min, v_max = params                         # cylindrical, with Blender's
        rx, ry, rz, rw = -u_min, -u_max, v_min, v_max               # sync of the range
        across = np.hypot(d[:, 0], d[:, 1])
        height = d[:, 2] / np.where(across > 0, across, np.nan)
        u = (np.arctan2(d[:, 1], d[:, 0]) - rx) / (ry - rx)
        v = (height - rz) / (rw - rz)
        return np.stack([u, v], 1), across > 0
    if model == "EQUIANGULAR_CUBEMAP_FACE":                         # direction_to_equiangular_
        u = 0.5 - np.arctan2(d[:, 1], d[:, 0]) * 2 / np.pi          # cubemap_face; behind, its
        v = np.arctan2(d[:, 2], d[:, 0]) * 2 / np.pi + 0.5          # atan2 jumps: not shown
        return np.stack([u, v], 1), d[:, 0] > 0
    theta = np.arccos(np.clip(d[:, 0], -1, 1))
    rho = np.hypot(d[:, 1], d[:, 2])
    cos_phi = np.where(rho > 0, -d[:, 1] / np.where(rho > 0, rho, 1), 1.0)  # inverse of
    sin_phi = np.where(rho > 0, d[:, 2] / np.where(rho > 0, rho, 1), 0.0)   # *_to_direction
    if model == "FISHEYE_EQUIDISTANT":
        (fov,) = params
        radius = 2 * theta / fov                                   # fisheye_to_direction
        return np.stack([0.5 * radius * cos_phi + 0.5, 0.5 * radius * sin_phi + 0.5], 1), \
            theta <= fov / 2
    if model == "FISHEYE_LENS_POLYNOMIAL":  # fisheye_lens_polynomial_to_direction, inverted
        *k, fov, sensor_w, sensor_h = params   # by bisection: theta = -p(r) rises with r

        def angle(r):
            return -(k[0] + k[1] * r + k[2] * r ** 2 + k[3] * r ** 3 + k[4] * r ** 4)
        lo, hi = np.zeros(len(p)), np.full(len(p), 2 * math.hypot(sensor_w, sensor_h))
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            below = angle(mid) < theta
            lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
        radius = 0.5 * (lo + hi)
        shows = (theta <= fov / 2) & (angle(radius) > theta - 1e-9)
        return np.stack([radius * cos_phi / sensor_w + 0.5, radius * sin_phi / sensor_h + 0.5],
                        1), shows
    if model == "FISHEYE_EQUISOLID":
        lens, fov, sensor_w, sensor_h = params
        radius = 2 * lens * np.sin(theta / 2)                      # fisheye_equisolid_to_direction
        return np.stack([radius * cos_phi / sensor_w + 0.5, radius * sin_phi / sensor_h + 0.5],
                        1), theta <= fov / 2
    raise ValueError(f"unknown camera model {model!r}")


def _uv_jacobian(p: np.ndarray, model: str, params, wraps: bool) -> np.ndarray:
    """d(u, v)/dp (N, 2, 3) by central differences in float64, independent of the native code's
    closed forms. Steps h = 1e-6 |p| and h/2, Richardson-extrapolated: the error falls from
    (h/l)^2 to (h/l)^4, l the mapping's own length scale, which near a central cylinder's poles
    is the distance from its axis (a Gaussian 8e-4 from it at |p| = 2.2 had c off by 1.5e-5)."""
    def central(step: np.ndarray) -> np.ndarray:
        jac = np.zeros((len(p), 2, 3))
        for k in range(3):
            offset = np.zeros_like(p)
            offset[:, k] = step
            diff = _cycles_uv(p + offset, model, params)[0] - _cycles_uv(p - offset, model, params)[0]
            if wraps:  # across the seam u jumps by a whole period
                diff[:, 0] -= np.round(diff[:, 0])
            jac[:, :, k] = diff / (2 * step[:, None])
        return jac

    step = 1e-6 * np.linalg.norm(p, axis=1)
    return (4 * central(step / 2) - central(step)) / 3


def wraps(model: str, params) -> bool:
    """Whether an equirectangular or central cylindrical image repeats across its left and right
    edges (360 degrees of longitude)."""
    return model in ("EQUIRECTANGULAR", "CENTRAL_CYLINDRICAL") and \
        params[1] - params[0] >= 2 * np.pi - 1e-6


def camera_model_project(means, log_scales, quats, opacity_logits, sh, viewmat, fx, fy, cx, cy,
                         width, height, *, near, far, antialiased, sh_degree, model,
                         model_params, aperture=0.0, focus=1.0) -> dict[str, np.ndarray]:
    """`project()` through an orthographic or a panoramic camera (docs/conventions.md,
    "Cameras beyond the pinhole").

    ORTHO: xy = (fx x + cx, fy y + cy), J = [[fx, 0, 0], [0, fy, 0]] exactly; depth z, culled
    outside [near, far]; the SH direction is the camera's forward axis for every Gaussian.
    Panoramas: (u, v) = Cycles' mapping of the direction, xy = (fx u + cx, cy - fy v), J the
    Jacobian of that at the mean; depth |p|, culled outside [near, far] and where the mapping
    shows nothing. With a 360-degree equirectangular or central cylindrical image, u is taken
    into [0, 1) and each Gaussian gets a copy one period P = 2 pi fx / (longitude range) over
    (towards the image), returned under "copies" (rows where the copy reaches no pixel are
    invalid); a Gaussian whose alpha >= 1/255 half-width sqrt(k2 Sigma_xx) (k2 = 2 ln(255
    sigmoid) (1 + 1e-4) + 1e-4) exceeds P/2 is a band instead: conic (0, 0, 1 / Sigma_yy), no
    copy, antialiasing factor sqrt(Sigma_yy before dilation / Sigma_yy).
    """
    means, log_scales, opacity_logits = _f64(means), _f64(log_scales), _f64(opacity_logits)
    sh, viewmat = _f64(sh), _f64(viewmat)
    fx, fy, cx, cy = (float(v) for v in (fx, fy, cx, cy))
    degree = sh_degree_of(sh) if sh_degree is None else min(int(sh_degree), sh_degree_of(sh))
    n = len(means)
    rv, tv = viewmat[:3, :3], viewmat[:3, 3]
    p_cam = means @ rv.T + tv
    rot = quat_to_rotmat(quats)
    cov3 = rot @ (np.exp(2 * log_scales)[:, :, None] * np.swapaxes(rot, 1, 2))
    cov_cam = rv @ cov3 @ rv.T
    opacity = 1.0 / (1.0 + np.exp(-opacity_logits))
    period = 2 * np.pi * fx / (model_params[1] - model_params[0]) if wraps(model, model_params) else 0.0

    with np.errstate(all="ignore"):
        if model == "ORTHO":
            depth = p_cam[:, 2]
            xy = np.stack([fx * p_cam[:, 0] + cx, fy * p_cam[:, 1] + cy], 1)
            jac = np.zeros((n, 2, 3))
            jac[:, 0, 0], jac[:, 1, 1] = fx, fy
            shows = np.ones(n, bool)
            dirs = np.broadcast_to(rv[2] / np.linalg.norm(rv[2]), (n, 3))
        else:
            depth = np.linalg.norm(p_cam, axis=1)
            uv, shows = _cycles_uv(p_cam, model, model_params)
            if period:
                uv[:, 0] -= np.floor(uv[:, 0])
            xy = np.stack([fx * uv[:, 0] + cx, cy - fy * uv[:, 1]], 1)
            jac = _uv_jacobian(p_cam, model, model_params, bool(period)) * np.array([fx, -fy])[:, None]
            centre = -rv.T @ tv
            dirs = (means - centre) / np.linalg.norm(means - centre, axis=1, keepdims=True)
        cov2 = jac @ cov_cam @ np.swapaxes(jac, 1, 2)
        conic, mass = depth_of_field(cov2, depth, fx, fy, aperture, focus, antialiased,
                                     model == "ORTHO")
        a, c = cov2[:, 0, 0] + DILATION, cov2[:, 1, 1] + DILATION
        det = 1.0 / (conic[:, 0] * conic[:, 2] - conic[:, 1] ** 2)
        k2 = 2 * np.log(255 * opacity) * (1 + 1e-4) + 1e-4
        band = (period > 0) & ~(k2 * a <= 0.25 * period ** 2)
        conic[band] = np.stack([0 * c, 0 * c, 1 / c], 1)[band]
        det = np.where(band, c, det)
        band_mass = np.sqrt(np.maximum(0.0, (c - DILATION) / c)) if antialiased else 1.0
        opacity = opacity * np.where(band, band_mass, mass)
        rgb = np.maximum(eval_sh(sh, dirs, degree) + 0.5, 0.0)
        valid = ((depth >= near) & (depth <= far) & shows & (det > 0) & np.isfinite(det)
                 & np.isfinite(xy).all(1) & np.isfinite(conic).all(1))
        valid &= np.isfinite(c) & (band | np.isfinite(a))

    def rows(xy, valid):
        xy, conic_v, rgb_v = xy.copy(), conic.copy(), rgb.copy()
        zero = ~valid
        xy[zero], conic_v[zero], rgb_v[zero] = 0.0, 0.0, 0.0
        return {"xy": xy, "conic": conic_v, "depth": np.where(valid, depth, 0.0),
                "opacity": np.where(valid, opacity, 0.0), "rgb": rgb_v, "valid": valid}

    out = rows(xy, valid)
    if period:
        shifted = xy.copy()
        shifted[:, 0] += np.where(uv[:, 0] < 0.5, period, -period)
        out["copies"] = rows(shifted, valid & ~band)
    return out


def window_depth(depth, projection) -> np.ndarray:
    """Planar depth (along the view, +inf: nothing) -> the depth-buffer value OpenGL stores for
    it under the 4x4 `projection` (default depth range [0, 1]; perspective or orthographic),
    float64: 0.5 ndc + 0.5 clipped to [0, 1], 1 where ndc is not finite (the native
    viewport_image's, addon/core/render/renderer.py)."""
    p = np.asarray(projection, np.float64)
    z = np.asarray(depth, np.float64)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        ndc = (p[2, 2] * -z + p[2, 3]) / (p[3, 2] * -z + p[3, 3])
    return np.clip(np.where(np.isfinite(ndc), 0.5 * ndc + 0.5, 1.0), 0.0, 1.0)
