"""Host side of the real-Blender test (the project's .venv, with OpenImageIO): makes the splats,
and holds what a real Blender wrote against the native composite computed here.

    python tests/real_blender/check.py make SPLATS.npz
    python tests/real_blender/check.py render WRITTEN.png MESHES.exr SPLATS.npz [CAMERA_KIND]
    python tests/real_blender/check.py viewport SPLATS_SHOT.png PLAIN_SHOT.png VIEW.json SPLATS.npz
    python tests/real_blender/check.py undo-splats SPLATS.ply
    python tests/real_blender/check.py undo OUT_DIR

`render`: WRITTEN (an 8-bit PNG from F12 or `-a`) must equal, within 1/255, the splats composed
by the native compositor with the meshes Blender rendered alone (MESHES, a multilayer EXR of the
same frame with Composite Splats off), encoded as the "Standard" view transform writes it.
The camera is the one `scene.py` builds, or made CAMERA_KIND (scene_kit.CAMERA_KINDS:
orthographic or panoramic; near = its clip_start, outside a fisheye's circle the meshes' pixel).

`viewport`: screenshots of the UI (`viewport_shot.py`: with the add-on's drawing and without)
against the native render at the viewport's own camera (VIEW: what the UI recorded). Prints
the figures; fails when they are off (see `viewport_figures`).

`undo`: the screenshots `undo_display.py` took through import, Clean Up, undo and redo, each held
against the native render of what the viewport showed (see `undo_figures`): no vertex dots.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from addon.core.images import exr_layers as exr  # noqa: E402
from addon.core.cameras import BlenderCameraParams, Camera, camera_from_blender  # noqa: E402
from addon.core.gaussians import Gaussians  # noqa: E402
from scenes import random_gaussians  # noqa: E402
from standard_view import native_composite, read_png, standard_8bit  # noqa: E402

WIDTH, HEIGHT = 64, 48


def make(path: str) -> None:
    g = random_gaussians(np.random.default_rng(20261124), 400, 1, radius=1.0, stray=0.0)
    np.savez(path, **g.arrays())


def make_undo_splats(path: str) -> None:
    """A dense, mostly opaque ball (dots over it are easy to see) and transparent floaters that
    Clean Up removes, as a .ply (the import's 3DGS frame: y down, z forward)."""
    from addon.core.formats import registry

    rng = np.random.default_rng(20261127)
    g = random_gaussians(rng, 6000, 1, radius=0.8, stray=0.0)
    g.log_scales[:] = rng.uniform(np.log(0.03), np.log(0.08), size=(6000, 1)) + \
        rng.normal(scale=0.2, size=(6000, 3))
    g.opacity_logits[:] = rng.normal(3.0, 1.0, size=6000)
    g.opacity_logits[:600] = -8.0
    registry.write(g, path)


def load(path: str) -> Gaussians:
    data = np.load(path)
    return Gaussians(data["means"], data["log_scales"], data["quats"], data["opacity_logits"],
                     data["sh"])


def scene_camera(kind: str | None = None) -> Camera:
    """scene.py's camera: at (0, -6, 0), rotated 90 degrees about X, 35 mm, 64x48; or that
    camera made `kind` (scene_kit.CAMERA_KINDS)."""
    from real_blender.scene_kit import CAMERA_KINDS

    c, s = math.cos(math.pi / 2), math.sin(math.pi / 2)
    matrix = np.array([[1, 0, 0, 0], [0, c, -s, -6.0], [0, s, c, 0], [0, 0, 0, 1]], np.float64)
    return camera_from_blender(BlenderCameraParams(
        matrix_world=matrix, lens=35.0, sensor_width=36.0, sensor_height=24.0,
        sensor_fit="AUTO", shift_x=0.0, shift_y=0.0, resolution_x=WIDTH, resolution_y=HEIGHT,
        resolution_percentage=100, pixel_aspect_x=1.0, pixel_aspect_y=1.0,
        **(CAMERA_KINDS[kind] if kind else {})))


def mesh_layers(path: str) -> tuple[np.ndarray, np.ndarray]:
    channels = exr.read_channels(path)
    rgba = exr.find_pass(channels, "ViewLayer", "Combined", "RGBA")
    depth = exr.find_pass(channels, "ViewLayer", "Depth", "Z")
    if rgba is None or depth is None:
        raise SystemExit(f"{path}: no ViewLayer Combined and Depth passes: {sorted(channels)}")
    return rgba, depth[..., 0]


def check_render(written: str, meshes: str, splats: str, kind: str | None = None) -> int:
    from addon.core.cameras import image_coverage

    mesh_rgba, mesh_depth = mesh_layers(meshes)
    camera = scene_camera(kind)
    composite = native_composite(load(splats), camera, mesh_rgba, mesh_depth,
                                 near=0.1 if kind else 0.01)  # clip_start, for those kinds
    shown = image_coverage(camera)
    if shown is not None:
        composite[~shown] = mesh_rgba[~shown]
    expected = standard_8bit(composite)
    got = read_png(written)
    if got.shape != expected.shape:
        print(f"FAIL {written}: {got.shape} pixels, expected {expected.shape}")
        return 1
    diff = np.abs(got - expected)
    meshes_only = standard_8bit(mesh_rgba)
    splat_effect = np.abs(expected - meshes_only).max()
    print(f"{written}: max error {diff.max()}/255 against the native composite "
          f"(the splats change pixels by up to {splat_effect}/255)")
    return 0 if diff.max() <= 1 and splat_effect > 20 else 1


if __name__ == "__main__":
    command, *args = sys.argv[1:]
    if command == "make":
        make(*args)
        code = 0
    elif command == "render":
        code = check_render(*args)
    elif command == "undo-splats":
        make_undo_splats(*args)
        code = 0
    elif command == "undo":
        from undo_figures import check_undo  # noqa: E402
        code = check_undo(*args)
    elif command == "viewport":
        from viewport_figures import check_viewport  # noqa: E402
        code = check_viewport(*args)
    else:
        raise SystemExit(__doc__)
    sys.exit(code)
