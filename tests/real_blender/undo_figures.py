"""The screenshots of `undo_display.py` held against the native render (host side).

For each step, the splats the viewport showed (its .npz) are rendered natively from the view the
UI recorded, as the add-on's draw handler renders them (`viewport.render_view`). Where they are
opaque (alpha > 0.98), the screenshot must show their colour: pixels off by more than 24 levels
are what the viewport check counts (vertex dots, a failed depth test). The bounding box Blender
draws for a Bounds display crosses the splats in thin lines; a band of 3 pixels about its
projected edges is left out, and what is off outside it are the dot pixels: Blender's vertex
dots, one per splat, drawn over the add-on's image when the object is not displayed as Bounds.
Edit Mode steps show their points by design and are reported, not held to it. The last step (`control_dots`)
displays the object as Blender would by itself: there the dots must be seen, or the check is blind.
"""

from __future__ import annotations

import json
import os

import numpy as np

from addon.core.gaussians import Gaussians
from standard_view import read_png

MAX_OFF_SHARE = 0.01     # the viewport check's bound (vertex dots, a failed depth test)
MIN_SPLAT_PIXELS = 1000
MAX_DOT_PIXELS = 20      # off pixels outside the box's band (a few at antialiased edges)
MIN_CONTROL_DOT_PIXELS = 60  # Display As Textured: its dots must be seen


def box_band(means: np.ndarray, camera, width: int, height: int, pixels: int = 3) -> np.ndarray:
    """(height, width) bool: within `pixels` of the projected edges of the box about `means`
    (the bounding box Blender draws for Display As Bounds, axis-aligned in the world here)."""
    lo, hi = means.min(0), means.max(0)
    corners = np.array([[(hi if i & 1 else lo)[0], (hi if i & 2 else lo)[1],
                         (hi if i & 4 else lo)[2]] for i in range(8)], np.float64)
    w2c = np.asarray(camera.world_to_camera, np.float64)
    cam = corners @ w2c[:3, :3].T + w2c[:3, 3]
    uv = np.stack([camera.fx * cam[:, 0] / cam[:, 2] + camera.cx,
                   camera.fy * cam[:, 1] / cam[:, 2] + camera.cy], 1)
    band = np.zeros((height, width), bool)
    ys, xs = np.mgrid[0:height, 0:width]
    for a in range(8):
        for b in range(8):
            if a < b and bin(a ^ b).count("1") == 1:  # an edge: corners differing in one axis
                p, q = uv[a], uv[b]
                d = q - p
                t = np.clip(((xs - p[0]) * d[0] + (ys - p[1]) * d[1]) / max(d @ d, 1e-9), 0, 1)
                band |= np.hypot(xs - p[0] - t * d[0], ys - p[1] - t * d[1]) <= pixels
    return band


def step_figures(shot: np.ndarray, entry: dict, npz: str) -> dict:
    from addon.blender.viewport import camera_from_view, render_view

    data = np.load(npz)
    gaussians = Gaussians(data["means"], data["log_scales"], data["quats"],
                          data["opacity_logits"], data["sh"])
    width, height = entry["region"]
    view, window = np.array(entry["view_matrix"]), np.array(entry["window_matrix"])
    camera = camera_from_view(view, window, width, height)
    image = render_view(gaussians, camera, window, **entry["options"])
    rgba = image.rgba[::-1]                      # rows top to bottom, as the screenshot
    alpha = rgba[..., 3]
    expected = np.clip(rgba[..., :3] / np.maximum(alpha, 1e-6)[..., None], 0, 1) * 255
    opaque = alpha > 0.98
    got = shot[:height, :width, :3].astype(np.float64)
    off = np.abs(got - expected).max(-1) > 24
    errors = np.abs(got - expected).max(-1)[opaque]
    band = box_band(gaussians.means, camera, width, height)
    return {"splat_pixels": int(opaque.sum()),
            "dot_pixels": int((off & opaque & ~band).sum()),
            "off_share": float((errors > 24).mean()) if errors.size else float("nan"),
            "p99_error": float(np.percentile(errors, 99)) if errors.size else float("nan")}


def check_undo(out_dir: str) -> int:
    record = json.load(open(os.path.join(out_dir, "steps.json")))
    failures = list(record["errors"])
    expected_steps = ["import", "clean_up", "undo", "redo", "edit_delete", "edit_undo",
                      "undo_edit", "control_dots"]
    names = [entry["name"] for entry in record["steps"]]
    if names != expected_steps:
        failures.append(f"steps recorded: {names}, expected {expected_steps}")
    points = {}
    for entry in record["steps"]:
        name = entry["name"]
        points[name] = entry.get("splats", 0)
        npz = os.path.join(out_dir, f"{name}.npz")
        if "options" not in entry or not os.path.exists(npz):
            failures.append(f"{name}: the viewport showed no splats")
            continue
        result = step_figures(read_png(os.path.join(out_dir, f"{name}.png")), entry, npz)
        edit = entry["mode"] == "EDIT_MESH"
        print(f"{name:12s} {entry['mode']:9s} display {entry['display_type']:8s} "
              f"{entry.get('splats', 0):6d} splats shown: {result['splat_pixels']} splat pixels, "
              f"{100 * result['off_share']:.2f}% off by > 24 levels, p99 {result['p99_error']:.0f}, "
              f"{result['dot_pixels']} dot pixels"
              + ("  (Edit Mode: points shown by design)" if edit else "")
              + ("  (control: dots must be seen)" if name == "control_dots" else ""))
        if edit:
            continue
        if name == "control_dots":
            if entry["display_type"] != "TEXTURED" \
                    or not result["dot_pixels"] >= MIN_CONTROL_DOT_PIXELS:
                failures.append(f"control: Display As {entry['display_type']} gives only "
                                f"{result['dot_pixels']} dot pixels: the check cannot see dots")
            continue
        if entry["display_type"] != "BOUNDS":
            failures.append(f"{name}: displayed as {entry['display_type']}, not BOUNDS")
        if result["splat_pixels"] < MIN_SPLAT_PIXELS or not result["off_share"] <= MAX_OFF_SHARE \
                or result["dot_pixels"] > MAX_DOT_PIXELS:
            failures.append(f"{name}: {100 * result['off_share']:.2f}% of "
                            f"{result['splat_pixels']} splat pixels off, "
                            f"{result['dot_pixels']} dot pixels (vertex dots)")
    # The edits must have happened and been undone (else the test tested nothing).
    if len(points) == len(expected_steps) and not (
            points["clean_up"] < points["import"] == points["undo"]
            and points["redo"] == points["clean_up"] == points["undo_edit"]
            and points["edit_delete"] < points["edit_undo"] == points["clean_up"]):
        failures.append(f"the point counts do not show the edits and their undo: {points}")
    for failure in failures:
        print(f"FAIL {failure}")
    return 1 if failures else 0
