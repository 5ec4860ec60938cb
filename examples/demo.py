"""The README's demo: load the shipped splat scene and render it to out/demo.png.

Run with the project's environment: `.venv/bin/python examples/demo.py` (the README's first command).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from addon.core import splat_io  # noqa: E402
from addon.core.cameras import Camera  # noqa: E402
from addon.core.images.files import write_image  # noqa: E402
from addon.core.render.renderer import render  # noqa: E402


def main() -> None:
    gaussians = splat_io.load(ROOT / "examples" / "demo_scene.ply")
    camera = Camera.look_at(eye=(5.5, -6.0, 3.2), target=(0.0, 0.0, 0.9), up=(0, 0, 1),
                            width=960, height=540, fov_x_degrees=50)
    start = time.perf_counter()
    result = render(gaussians, camera)  # transparent background: the PNG keeps alpha
    elapsed = time.perf_counter() - start
    out = ROOT / "out"
    out.mkdir(exist_ok=True)
    write_image(out / "demo.png", result.rgb, result.alpha)
    print(f"rendered {len(gaussians)} Gaussians at {camera.width}x{camera.height} in "
          f"{1000 * elapsed:.1f} ms -> {out / 'demo.png'}")


if __name__ == "__main__":
    main()
