"""Float64 NumPy twins of the deformation stages (addon/core/deform: native/src/neighbours.c,
deform_fit.c, deform_apply.c), written for clarity, one point at a time where that is plainer;
and analytic deformations with known Jacobians (a bend, a twist) that the tests, the Blender
renders and benchmarks/bench_deform.py hold the estimates against."""

from __future__ import annotations

import numpy as np

from addon.core.gaussians import Gaussians
from addon.core.transform import reshape_covariances, rotate_sh


def neighbours(points: np.ndarray, k: int) -> np.ndarray:
    """Brute force: the k nearest other points by squared float64 distance, ties to the lower
    index, -1 where fewer exist."""
    p = np.asarray(points, np.float32).astype(np.float64)
    n = len(p)
    diff = p[None, :, :] - p[:, None, :]
    d2 = diff[..., 0] * diff[..., 0] + diff[..., 1] * diff[..., 1] + diff[..., 2] * diff[..., 2]
    np.fill_diagonal(d2, np.inf)
    index = np.broadcast_to(np.arange(n), (n, n))
    order = np.lexsort((index, d2), axis=-1)[:, :k]
    out = np.full((n, k), -1, np.int32)
    have = min(k, n - 1)
    out[:, :have] = order[:, :have]
    return out


def ramp(ratio: float, lo: float, hi: float) -> float:
    """The weight c_m of a direction whose spread is `ratio` of the widest (deform_fit.c)."""
    if ratio <= lo or ratio <= 1e-12:  # rounding-level spread: flat, whatever lo is
        return 0.0
    return 1.0 if ratio >= hi else (ratio - lo) / (hi - lo)


def rotation_between(e: np.ndarray, d: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit e to unit d (Rodrigues about e x d)."""
    v, c = np.cross(e, d), float(e @ d)
    if c > -1.0 + 1e-12:
        vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
        return np.eye(3) + vx + vx @ vx / (1.0 + c)
    axis = int(np.argmin(np.abs(e)))
    u = np.eye(3)[axis] - e[axis] * e
    u /= np.linalg.norm(u)
    return 2.0 * np.outer(u, u) - np.eye(3)


def polar(m: np.ndarray) -> np.ndarray | None:
    """The orthogonal polar factor U V^T, None where m is singular to 1e-12 of its size."""
    size = np.linalg.norm(m)
    if not size > 0 or not abs(np.linalg.det(m)) > 1e-12 * size ** 3:
        return None
    u, _, vt = np.linalg.svd(m)
    return u @ vt


def jacobians(rest: np.ndarray, deformed: np.ndarray, nbrs: np.ndarray, undetermined: float,
              determined: float) -> tuple[np.ndarray, np.ndarray]:
    """addon/core/deform/jacobians.py's J and rotation per point, in float64."""
    rest = np.asarray(rest, np.float32).astype(np.float64)
    deformed = np.asarray(deformed, np.float32).astype(np.float64)
    n = len(rest)
    out_j = np.tile(np.eye(3), (n, 1, 1))
    out_q = out_j.copy()
    for i in range(n):
        valid = nbrs[i][nbrs[i] >= 0]
        a, b = rest[valid] - rest[i], deformed[valid] - deformed[i]
        d2 = (a * a).sum(axis=1)
        if not len(valid) or not d2.max() > 0:
            continue
        w = np.exp(-d2 / d2.max())
        spread, cross = (w[:, None] * a).T @ a, (w[:, None] * b).T @ a
        values, vectors = np.linalg.eigh(spread)
        lam = values[::-1]
        e = [vectors[:, 2], vectors[:, 1]]
        e.append(np.cross(e[0], e[1]))
        c = [1.0] + [ramp(lam[m] / lam[0], undetermined, determined) for m in (1, 2)]
        f = [cross @ e[m] / lam[m] if c[m] > 0 else np.zeros(3) for m in range(3)]
        rotation = np.eye(3)
        if np.linalg.norm(f[0]) > 0:
            d1 = f[0] / np.linalg.norm(f[0])
            rotation = rotation_between(e[0], d1)
            if c[1] > 0:
                turned = rotation @ e[1]
                u = (c[1] * f[1] / np.linalg.norm(f[1]) if np.linalg.norm(f[1]) > 0 else 0.0) \
                    + (1 - c[1]) * turned
                u = u - (u @ d1) * d1
                if not u @ u > 1e-24:
                    u = turned - (turned @ d1) * d1
                d2v = u / np.linalg.norm(u)
                rotation = sum(np.outer(d, em) for d, em in zip((d1, d2v, np.cross(d1, d2v)), e))
        jac = sum(np.outer(c[m] * f[m] + (1 - c[m]) * rotation @ e[m], e[m]) for m in range(3))
        out_j[i] = jac
        q = polar(jac)
        out_q[i] = rotation if q is None else q
    return out_j, out_q


def spread_ratios(rest: np.ndarray, nbrs: np.ndarray) -> np.ndarray:
    """(N, 2): l_2 / l_1 and l_3 / l_1 of each point's weighted neighbour spread (0 without
    neighbours): which directions the fit determines."""
    rest = np.asarray(rest, np.float32).astype(np.float64)
    out = np.zeros((len(rest), 2))
    for i in range(len(rest)):
        a = rest[nbrs[i][nbrs[i] >= 0]] - rest[i]
        d2 = (a * a).sum(axis=1)
        if len(a) and d2.max() > 0:
            values = np.linalg.eigvalsh((np.exp(-d2 / d2.max())[:, None] * a).T @ a)
            out[i] = values[1] / values[2], values[0] / values[2]
    return out


def deformed(gaussians: Gaussians, jacobians_: np.ndarray, rotations: np.ndarray) -> Gaussians:
    """Each Gaussian's covariance through its J (core.transform's eigen-decomposition) and its
    SH through its rotation (core.transform.rotate_sh), one Gaussian at a time."""
    quats, log_scales = reshape_covariances(gaussians, jacobians_)
    sh = np.concatenate([rotate_sh(gaussians.sh[i:i + 1], rotations[i])
                         for i in range(len(gaussians))]) if len(gaussians) else gaussians.sh
    return Gaussians(gaussians.means, log_scales, quats, gaussians.opacity_logits, sh)


# -- analytic deformations: (points (N, 3) float64) -> (moved points, Jacobians (N, 3, 3))

def bend(points: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Bend about the Z axis through (0, radius, 0): x along the arc, y towards the centre."""
    x, y, z = np.asarray(points, np.float64).T
    phi = x / radius
    s, c = np.sin(phi), np.cos(phi)
    moved = np.stack([(radius - y) * s, radius - (radius - y) * c, z], axis=1)
    jac = np.zeros((len(x), 3, 3))
    jac[:, 0, 0], jac[:, 1, 0] = (radius - y) * c / radius, (radius - y) * s / radius
    jac[:, 0, 1], jac[:, 1, 1] = -s, c
    jac[:, 2, 2] = 1.0
    return moved, jac


def twist(points: np.ndarray, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """Twist about the Z axis by `rate` radians per unit of z."""
    x, y, z = np.asarray(points, np.float64).T
    s, c = np.sin(rate * z), np.cos(rate * z)
    moved = np.stack([x * c - y * s, x * s + y * c, z], axis=1)
    jac = np.zeros((len(x), 3, 3))
    jac[:, 0, 0], jac[:, 0, 1], jac[:, 0, 2] = c, -s, -rate * (x * s + y * c)
    jac[:, 1, 0], jac[:, 1, 1], jac[:, 1, 2] = s, c, rate * (x * c - y * s)
    jac[:, 2, 2] = 1.0
    return moved, jac
