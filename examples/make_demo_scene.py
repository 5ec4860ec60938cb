"""Builds examples/demo_scene.ply, the small splat scene the README's demo renders.

A procedural scene, so the project ships no third-party data: a striped planet of Gaussians on
a chequered ground, with degree-1 SH that makes the planet's sheen follow the viewer. Run it
again to rebuild the file (it is deterministic).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from addon.core import splat_io  # noqa: E402
from addon.core.gaussians import Gaussians  # noqa: E402
from addon.core.sh import SH_C0 as C0  # noqa: E402


def _to_sh_dc(rgb: np.ndarray) -> np.ndarray:
    return (rgb - 0.5) / C0


def planet(rng: np.random.Generator, n: int) -> Gaussians:
    # Points on a unit sphere at z = 1, flattened Gaussians tangent to it.
    normal = rng.normal(size=(n, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    means = normal + [0.0, 0.0, 1.0]
    # Quaternion taking +z to the normal: flat discs lie on the surface.
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, normal)
    w = 1.0 + normal @ z
    quats = np.concatenate([w[:, None], axis], axis=1)
    quats[w < 1e-6] = [0, 1, 0, 0]
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    log_scales = np.log(np.stack([np.full(n, 0.045), np.full(n, 0.045), np.full(n, 0.006)], 1))
    latitude = np.arcsin(normal[:, 2])
    stripes = 0.5 + 0.5 * np.sin(9 * latitude)
    rgb = np.stack([0.9 * stripes + 0.1, 0.35 + 0.3 * stripes, 0.8 - 0.6 * stripes], 1)
    sh = np.zeros((n, 4, 3))
    sh[:, 0] = _to_sh_dc(rgb)
    # Degree 1 basis is C1 * (-y, z, -x) of the view direction d; these coefficients add
    # -0.15 C1 (d . normal): a sheen where the surface faces the viewer.
    sheen = 0.15 * np.stack([normal[:, 1], -normal[:, 2], normal[:, 0]], 1)
    sh[:, 1:, :] = sheen[:, :, None]
    return Gaussians(means, log_scales, quats, np.full(n, 3.0), sh)


def ring(rng: np.random.Generator, n: int) -> Gaussians:
    angle = rng.uniform(0, 2 * np.pi, n)
    radius = rng.uniform(1.4, 1.9, n)
    means = np.stack([radius * np.cos(angle), radius * np.sin(angle) * 0.94,
                      1.0 + radius * np.sin(angle) * 0.34], 1)
    rgb = np.stack([0.9 - 0.3 * (radius - 1.4), 0.85 - 0.4 * (radius - 1.4), 0.6 + 0 * radius], 1)
    sh = np.zeros((n, 4, 3))
    sh[:, 0] = _to_sh_dc(rgb)
    log_scales = np.log(np.full((n, 3), 0.02))
    quats = np.tile([1.0, 0, 0, 0], (n, 1))
    return Gaussians(means, log_scales, quats, np.full(n, 0.5), sh)


def ground(rng: np.random.Generator, n: int) -> Gaussians:
    xy = rng.uniform(-3.5, 3.5, (n, 2))
    means = np.concatenate([xy, np.zeros((n, 1))], 1)
    checker = (np.floor(xy[:, 0]) + np.floor(xy[:, 1])) % 2
    rgb = np.stack([0.25 + 0.5 * checker, 0.3 + 0.45 * checker, 0.35 + 0.4 * checker], 1)
    sh = np.zeros((n, 4, 3))
    sh[:, 0] = _to_sh_dc(rgb)
    log_scales = np.log(np.stack([np.full(n, 0.06), np.full(n, 0.06), np.full(n, 0.004)], 1))
    quats = np.tile([1.0, 0, 0, 0], (n, 1))
    return Gaussians(means, log_scales, quats, np.full(n, 4.0), sh)


def build() -> Gaussians:
    rng = np.random.default_rng(2026)
    parts = [planet(rng, 6000), ring(rng, 3000), ground(rng, 9000)]
    return Gaussians(*(np.concatenate([getattr(p, name) for p in parts])
                       for name in ("means", "log_scales", "quats", "opacity_logits", "sh")))


if __name__ == "__main__":
    path = ROOT / "examples" / "demo_scene.ply"
    gaussians = build()
    splat_io.save(gaussians, path)
    print(f"wrote {path} ({len(gaussians)} Gaussians, SH degree {gaussians.degree}, "
          f"{path.stat().st_size / 1e6:.2f} MB)")
