"""The viewport screenshots of `viewport_shot.py` held against the native render (host side).

The view's camera comes from the matrices the UI recorded (`viewport.camera_from_view`, as the
add-on draws it). The splats alone are rendered natively from it; the meshes' depth is ray-cast
here from `scene.py`'s geometry (a cube 0.9 wide at (0.35, -2.5, 0.15), a plane at y = 2.5).
Three figures, in 8-bit levels:

- splats: where the native splats are opaque (alpha > 0.98) and in front of every mesh, the
  screenshot must show their colour: mean and 99th percentile of |screenshot - native|, and
  the share of those pixels off by more than 24 levels (vertex dots, a failed depth test);
- occlusion: where the cube is in front of visible splats (alpha > 0.5 behind it; 2 pixels in
  from its antialiased silhouette), the screenshot must equal the one with the add-on's drawing
  off (the cube hides the splats);
- shown: the splats must change the image where they are opaque (mean difference from the
  screenshot without them).
"""

from __future__ import annotations

import json

import numpy as np

from addon.core.render.renderer import render
from standard_view import read_png

CUBE_MIN = np.array([0.35 - 0.45, -2.5 - 0.45, 0.15 - 0.45])
CUBE_MAX = np.array([0.35 + 0.45, -2.5 + 0.45, 0.15 + 0.45])
PLANE_Y = 2.5


def mesh_depth(camera) -> tuple[np.ndarray, np.ndarray]:
    """Planar depth of the nearest mesh per pixel (inf: none), and where the cube is nearest."""
    w2c = np.asarray(camera.world_to_camera, np.float64)
    rotation, origin = w2c[:3, :3].T, -w2c[:3, :3].T @ w2c[:3, 3]
    u, v = np.meshgrid(np.arange(camera.width) + 0.5, np.arange(camera.height) + 0.5)
    x, y = (u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy
    if camera.model == "ORTHO":  # parallel rays from the image plane through the origin
        origin = origin + np.stack([x, y, np.zeros_like(u)], -1) @ rotation.T
        x, y = np.zeros_like(u), np.zeros_like(u)
    rays = np.stack([x, y, np.ones_like(u)], -1) @ rotation.T          # world, unit planar depth
    with np.errstate(divide="ignore", invalid="ignore"):
        t_plane = (PLANE_Y - origin[..., 1]) / rays[..., 1]
        t0 = (CUBE_MIN - origin) / rays
        t1 = (CUBE_MAX - origin) / rays
    near = np.nanmax(np.minimum(t0, t1), -1)
    far = np.nanmin(np.maximum(t0, t1), -1)
    ahead = -np.inf if camera.model == "ORTHO" else 0  # an orthographic view sees behind its origin
    t_cube = np.where((far >= near) & (near > ahead), near, np.inf)
    t_plane = np.where(t_plane > ahead, t_plane, np.inf)
    return np.minimum(t_cube, t_plane), t_cube < t_plane


def _eroded(mask: np.ndarray, pixels: int) -> np.ndarray:
    """`mask` without its border (the cube's antialiased silhouette mixes in what is behind)."""
    out = mask.copy()
    for _ in range(pixels):
        inner = out.copy()
        inner[1:] &= out[:-1]
        inner[:-1] &= out[1:]
        inner[:, 1:] &= out[:, :-1]
        inner[:, :-1] &= out[:, 1:]
        out = inner
    return out


def figures(shot_splats: np.ndarray, shot_plain: np.ndarray, view: dict, gaussians) -> dict:
    from addon.blender.viewport import camera_from_view, view_near

    width, height = view["region"]
    camera = camera_from_view(np.array(view["view_matrix"]), np.array(view["window_matrix"]),
                              width, height)
    native = render(gaussians, camera, near=view_near(np.array(view["window_matrix"]), 0.01))
    depth, cube = mesh_depth(camera)
    s = shot_splats[:height, :width, :3].astype(np.float64)
    p = shot_plain[:height, :width, :3].astype(np.float64)
    expected = np.clip(native.rgb, 0, 1) * 255
    front = (native.alpha > 0.98) & (native.depth < depth)
    errors = np.abs(s - expected).max(-1)[front]
    hidden = _eroded(cube, 2) & (native.alpha > 0.5) & (native.depth > depth)
    return {
        "splat_pixels": int(front.sum()),
        "splat_mean_error": float(errors.mean()) if errors.size else float("nan"),
        "splat_p99_error": float(np.percentile(errors, 99)) if errors.size else float("nan"),
        "splat_off_share": float((errors > 24).mean()) if errors.size else float("nan"),
        "occluded_pixels": int(hidden.sum()),
        "occluded_max_change": float(np.abs(s - p).max(-1)[hidden].max()) if hidden.any() else 0.0,
        "shown_mean_change": float(np.abs(s - p).max(-1)[front].mean()) if front.any() else 0.0,
    }


def check_viewport(splats_png: str, plain_png: str, view_json: str, splats_npz: str) -> int:
    from check import load

    result = figures(read_png(splats_png), read_png(plain_png), json.load(open(view_json)),
                     load(splats_npz))
    print(f"{splats_png}: " + ", ".join(f"{k} {v:.3g}" for k, v in result.items()))
    # Views from the side or the top see the cube beside the splats: nothing to occlude there.
    occludes = json.load(open(view_json)).get("occludes", True)
    ok = (result["splat_pixels"] > 1000 and result["splat_off_share"] <= 0.01
          and result["splat_p99_error"] <= 12
          and (result["occluded_pixels"] > 1000 or not occludes)
          and result["occluded_max_change"] <= 2 and result["shown_mean_change"] > 20)
    return 0 if ok else 1
