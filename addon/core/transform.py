"""Transform Gaussians by a 4x4 matrix: centres, shapes and view-dependent colour together.

`transform_gaussians(gaussians, matrix)` returns the Gaussians a renderer should see when an
object holding `gaussians` in its local space has world matrix `matrix` (Blender's
`matrix_world`, column vectors: `x_world = M @ x_local`). Pure numpy; no bpy, no mathutils.

What happens, with `A` the linear 3x3 part and `t` the translation:

- means: `A m + t`, in float64, rounded once to float32.
- SH: the colour a Gaussian shows along a world direction `d` must be the colour it showed
  along the matching local direction. For an orthogonal `Q` (a rotation, or a rotation with a
  mirror) that is exactly `f'(d) = f(Q^T d)`, and each band l = 1..3 of real SH coefficients
  maps linearly onto itself: `c'_l = D_l(Q) c_l` (the real Wigner-D matrix in the 3DGS basis;
  band 0 is untouched). `sh_rotation_matrices(Q)` builds the D_l directly from the 3DGS basis
  of `computeColorFromSH` (the one in native/src/sh.c and tests/reference.py), by solving
  `Y_l(d_i) D_l = Y_l(Q^T d_i)` on a fixed set of well-spread directions d_i; because each band
  is an invariant subspace of O(3) the solution is exact to float64 rounding, and no sign or
  ordering convention can slip in. For a general `A`, `Q` is the orthogonal factor of its polar
  decomposition `A = Q P` (`Q = U V^T` from the SVD `A = U S V^T`), the closest orthogonal
  matrix to `A`: a non-uniform scale bends view directions in a way no SH rotation can
  express, and Q is the best single rotation (exact when the scale is uniform).
- shapes: the covariance `Σ = R diag(exp(2 s)) R^T` of each Gaussian becomes `A Σ A^T`, which is
  exactly the shape the transformed Gaussian has, for any invertible A.
  * Similarity (`A = k Q`, k > 0, all singular values equal to 1e-6 relative): the quaternion
    is composed with Q's rotation (`q' = q_Q ⊗ q`, with `-Q` used for a mirrored Q, since
    `(-Q) Σ (-Q)^T = Q Σ Q^T`) and `log k` is added to every log-scale. Cheap, and the axes keep
    their order and meaning.
  * Anything else (non-uniform or sheared scale): `A Σ A^T` is formed in float64 and split again
    by a symmetric eigen-decomposition into a rotation (eigenvectors, made right-handed) and
    scales (square roots of the eigenvalues, in ascending order). Exact for the Gaussian's
    shape; the axis order of the result is the eigenvalue order, not the original one.
    A singular A (a zero scale) flattens Gaussians: variances are floored at 1e-24 times the
    largest of that Gaussian (and at 1e-36 absolute) so log-scales stay finite.
- opacity is unchanged (an opacity is not a density: scaling a Gaussian does not change how
  opaque its centre looks).

`quaternions` are (w, x, y, z) and need not be normalised; an all-zero quaternion means the
identity, as everywhere in this project. Rotated quaternions keep their length (a zero one
becomes the rotation itself).
"""

from __future__ import annotations

import functools

import numpy as np

from .gaussians import Gaussians
from .sh import SH_C0 as _C0, SH_C1 as _C1, SH_C2 as _C2, SH_C3 as _C3

BAND_SLICES = {1: slice(1, 4), 2: slice(4, 9), 3: slice(9, 16)}
SIMILARITY_RTOL = 1e-6  # singular values equal to this (relative): treated as a similarity
_VARIANCE_FLOOR_REL = 1e-24
_VARIANCE_FLOOR_ABS = 1e-36


def sh_basis(dirs: np.ndarray, degree: int = 3) -> np.ndarray:
    """The 3DGS real SH basis (M, (degree+1)^2) at unit directions (M, 3), float64."""
    d = np.asarray(dirs, np.float64)
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    cols = [np.full_like(x, _C0)]
    if degree >= 1:
        cols += [-_C1 * y, _C1 * z, -_C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        cols += [_C2[0] * x * y, _C2[1] * y * z, _C2[2] * (2 * zz - xx - yy), _C2[3] * x * z,
                 _C2[4] * (xx - yy)]
    if degree >= 3:
        cols += [_C3[0] * y * (3 * xx - yy), _C3[1] * x * y * z, _C3[2] * y * (4 * zz - xx - yy),
                 _C3[3] * z * (2 * zz - 3 * xx - 3 * yy), _C3[4] * x * (4 * zz - xx - yy),
                 _C3[5] * z * (xx - yy), _C3[6] * x * (xx - 3 * yy)]
    return np.stack(cols, axis=1)


@functools.lru_cache(maxsize=1)
def _sample_directions() -> np.ndarray:
    """64 well-spread unit directions (a Fibonacci sphere): plenty to pin down band 3 (7 dims)."""
    n = 64
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z * z)
    phi = np.pi * (1.0 + 5.0 ** 0.5) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


@functools.lru_cache(maxsize=1)
def _basis_pinv() -> dict[int, np.ndarray]:
    basis = sh_basis(_sample_directions(), 3)
    return {band: np.linalg.pinv(basis[:, s]) for band, s in BAND_SLICES.items()}


def sh_rotation_matrices(orthogonal: np.ndarray) -> dict[int, np.ndarray]:
    """{band: D_l} for l = 1, 2, 3 such that coefficients `D_l @ c_l` show along `Q d` the colour
    `c_l` showed along `d`, for an orthogonal 3x3 `Q` (rotation or rotation with a mirror)."""
    q = np.asarray(orthogonal, np.float64)
    if q.shape != (3, 3):
        raise ValueError(f"expected a 3x3 matrix, got shape {q.shape}")
    if not np.allclose(q @ q.T, np.eye(3), atol=1e-9):
        raise ValueError("SH can only be rotated by an orthogonal matrix")
    # f'(d) = f(Q^T d): rows d_i^T Q are the directions (Q^T d_i)^T.
    rotated = sh_basis(_sample_directions() @ q, 3)
    pinv = _basis_pinv()
    return {band: pinv[band] @ rotated[:, s] for band, s in BAND_SLICES.items()}


def rotate_sh(sh: np.ndarray, orthogonal: np.ndarray) -> np.ndarray:
    """(N, K, 3) coefficients rotated by the orthogonal `Q` (band 0 copied bit for bit)."""
    sh = np.asarray(sh, np.float32)
    out = sh.copy()
    n, k = sh.shape[0], sh.shape[1]
    if k == 1 or n == 0:
        return out
    for band, matrix in sh_rotation_matrices(orthogonal).items():
        s = BAND_SLICES[band]
        if s.stop > k:
            break
        width = s.stop - s.start
        # (N, width, 3) -> (N, 3*width) @ kron(D, I3)^T: one float32 GEMM per band.
        block = np.kron(matrix, np.eye(3)).T.astype(np.float32)
        out[:, s, :] = (sh[:, s, :].reshape(n, 3 * width) @ block).reshape(n, width, 3)
    return out


def quat_to_matrix(quats: np.ndarray) -> np.ndarray:
    """(N, 4) w, x, y, z (any length; all zero = identity) -> (N, 3, 3) float64 rotations."""
    q = np.asarray(quats, np.float64)
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    q = np.where(norm > 0, q / np.where(norm > 0, norm, 1.0), np.array([1.0, 0.0, 0.0, 0.0]))
    w, x, y, z = q.T
    out = np.empty((len(q), 3, 3))  # filled in place: np.stack of the rows costs a third more
    out[:, 0] = np.column_stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)])
    out[:, 1] = np.column_stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)])
    out[:, 2] = np.column_stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)])
    return out


def matrix_to_quat(matrices: np.ndarray) -> np.ndarray:
    """(N, 3, 3) proper rotations -> (N, 4) unit quaternions w, x, y, z with w >= 0 (float64).

    Shepperd's method: the largest of the four candidate pivots keeps it well conditioned."""
    m = np.asarray(matrices, np.float64).reshape(-1, 3, 3)
    trace = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    pivots = np.stack([trace, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], axis=1)
    which = np.argmax(pivots, axis=1)
    q = np.empty((len(m), 4))
    # w largest
    s = np.sqrt(np.maximum(1.0 + trace, 0.0)) * 2.0
    q_w = np.stack([0.25 * s, (m[:, 2, 1] - m[:, 1, 2]), (m[:, 0, 2] - m[:, 2, 0]),
                    (m[:, 1, 0] - m[:, 0, 1])], axis=1)
    q_w[:, 1:] /= np.where(s > 0, s, 1.0)[:, None]
    # x largest
    s = np.sqrt(np.maximum(1.0 + m[:, 0, 0] - m[:, 1, 1] - m[:, 2, 2], 0.0)) * 2.0
    q_x = np.stack([(m[:, 2, 1] - m[:, 1, 2]), 0.25 * s, (m[:, 0, 1] + m[:, 1, 0]),
                    (m[:, 0, 2] + m[:, 2, 0])], axis=1)
    q_x[:, [0, 2, 3]] /= np.where(s > 0, s, 1.0)[:, None]
    # y largest
    s = np.sqrt(np.maximum(1.0 - m[:, 0, 0] + m[:, 1, 1] - m[:, 2, 2], 0.0)) * 2.0
    q_y = np.stack([(m[:, 0, 2] - m[:, 2, 0]), (m[:, 0, 1] + m[:, 1, 0]), 0.25 * s,
                    (m[:, 1, 2] + m[:, 2, 1])], axis=1)
    q_y[:, [0, 1, 3]] /= np.where(s > 0, s, 1.0)[:, None]
    # z largest
    s = np.sqrt(np.maximum(1.0 - m[:, 0, 0] - m[:, 1, 1] + m[:, 2, 2], 0.0)) * 2.0
    q_z = np.stack([(m[:, 1, 0] - m[:, 0, 1]), (m[:, 0, 2] + m[:, 2, 0]),
                    (m[:, 1, 2] + m[:, 2, 1]), 0.25 * s], axis=1)
    q_z[:, :3] /= np.where(s > 0, s, 1.0)[:, None]
    q = np.choose(which[:, None], [q_w, q_x, q_y, q_z])
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return np.where(q[:, :1] < 0, -q, q)


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a ⊗ b of (..., 4) w, x, y, z quaternions (R(a ⊗ b) = R(a) R(b))."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a, np.float64), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b, np.float64), -1, 0)
    return np.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], axis=-1)


def polar_decomposition(linear: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`A = Q P`: Q orthogonal (det = sign(det A), or +1 for singular A), P symmetric positive
    semi-definite. Returns (Q, singular values of A, descending)."""
    a = np.asarray(linear, np.float64)
    u, s, vt = np.linalg.svd(a)
    q = u @ vt
    if np.linalg.det(a) == 0.0 and np.linalg.det(q) < 0:
        # singular: pick the proper rotation (flip the axis with the zero singular value)
        u[:, -1] = -u[:, -1]
        q = u @ vt
    return q, s


def similarity_parts(matrix: np.ndarray) -> tuple[float, np.ndarray] | None:
    """(k, Q) when the linear part of `matrix` is `k Q` (k > 0, Q orthogonal) to 1e-6, else None."""
    a = np.asarray(matrix, np.float64)[:3, :3]
    q, s = polar_decomposition(a)
    if s[-1] <= 0 or s[0] - s[-1] > SIMILARITY_RTOL * s[0]:
        return None
    return float(np.exp(np.mean(np.log(s)))), q


def _check_matrix(matrix: np.ndarray) -> np.ndarray:
    m = np.asarray(matrix, np.float64)
    if m.shape != (4, 4):
        raise ValueError(f"expected a 4x4 matrix, got shape {m.shape}")
    if not np.isfinite(m).all():
        raise ValueError("transform matrix has non-finite entries")
    if not np.array_equal(m[3], [0.0, 0.0, 0.0, 1.0]):
        raise ValueError("transform matrix must be affine (last row 0, 0, 0, 1)")
    return m


def affine_parts(matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(A, t): the linear part (3, 3) and translation (3,) of the affine 4x4 `matrix`, float64;
    ValueError for anything else (not 4x4, not finite, a last row other than 0 0 0 1)."""
    m = _check_matrix(matrix)
    return m[:3, :3].copy(), m[:3, 3].copy()


def transform_gaussians(gaussians: Gaussians, matrix: np.ndarray) -> Gaussians:
    """The Gaussians as seen after applying the affine 4x4 `matrix` (see the module docstring).

    The identity returns `gaussians` itself; a pure translation shares every array but `means`.
    Treat the result as read-only."""
    m = _check_matrix(matrix)
    a, t = m[:3, :3], m[:3, 3]
    if np.array_equal(a, np.eye(3)):
        if not t.any():
            return gaussians
        means = (gaussians.means.astype(np.float64) + t).astype(np.float32)
        return Gaussians(means, gaussians.log_scales, gaussians.quats, gaussians.opacity_logits,
                         gaussians.sh)

    means = (gaussians.means.astype(np.float64) @ a.T + t).astype(np.float32)
    similarity = similarity_parts(m)
    if similarity is not None:
        k, q = similarity
        rotation = q if np.linalg.det(q) > 0 else -q
        quats = gaussians.quats.astype(np.float64)
        zero = ~quats.any(axis=1)
        quats[zero] = (1.0, 0.0, 0.0, 0.0)
        quats = quat_multiply(matrix_to_quat(rotation[None])[0], quats)
        log_scales = gaussians.log_scales.astype(np.float64) + np.log(k)
    else:
        q, _ = polar_decomposition(a)
        quats, log_scales = reshape_covariances(gaussians, a)
    sh = rotate_sh(gaussians.sh, q)
    return Gaussians(means, log_scales, quats, gaussians.opacity_logits, sh)


def covariances(gaussians: Gaussians) -> np.ndarray:
    """(N, 3, 3) float64 covariances R diag(exp(2 s)) R^T."""
    r = quat_to_matrix(gaussians.quats)
    var = np.exp(2.0 * gaussians.log_scales.astype(np.float64))
    return (r * var[:, None, :]) @ np.swapaxes(r, 1, 2)


def reshape_covariances(gaussians: Gaussians, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Quaternions and log-scales of `A Σ A^T`, by eigen-decomposition, in chunks; `a` one 3x3
    matrix, or one per Gaussian (N, 3, 3) (the float64 twin of core/deform's native step)."""
    n = len(gaussians)
    a = np.asarray(a, np.float64)
    quats = np.empty((n, 4), np.float32)
    log_scales = np.empty((n, 3), np.float32)
    chunk = 1 << 18
    for lo in range(0, n, chunk):
        part = gaussians.subset(slice(lo, lo + chunk))
        # A R diag(exp(s)): the covariance is L L^T
        r = quat_to_matrix(part.quats)
        factor = ((a if a.ndim == 2 else a[lo:lo + chunk]) @ r) * np.exp(part.log_scales.astype(np.float64))[:, None, :]
        cov = factor @ np.swapaxes(factor, 1, 2)
        values, vectors = np.linalg.eigh(cov)
        floor = np.maximum(values[:, -1:] * _VARIANCE_FLOOR_REL, _VARIANCE_FLOOR_ABS)
        values = np.maximum(values, floor)
        flip = np.linalg.det(vectors) < 0
        vectors[flip, :, 0] *= -1.0
        quats[lo:lo + chunk] = matrix_to_quat(vectors)
        log_scales[lo:lo + chunk] = 0.5 * np.log(values)
    return quats, log_scales
