"""How much each real splat file expands: the bytes of Gaussians it declares per byte read, as
the readers measure it for `formats_common.limits.MAX_EXPANSION` (what the bound was chosen from).

    .venv/bin/python benchmarks/bench_expansion.py [--data ../shared/data/splats] [--synthetic 50000]

Loads every file (each streamed-SOG level's chunk, .spz, .ply, ...) under --data through
`splat_io.load`, recording what each reader passes to `limits.check_expansion` (the declared
count, SH degree and the bytes of every file it is made of). --synthetic N adds an untrained SH3
scene of N Gaussians (random positions, everything else constant: what compresses best while
still being genuine), saved as SOG, .spz v4 and v2. Prints one row per check, the worst last.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from addon.core import splat_io  # noqa: E402
from addon.core.formats import gltf, sog, spz  # noqa: E402
from addon.core.formats_common import limits  # noqa: E402
from addon.core.gaussians import Gaussians  # noqa: E402

ROWS: list[tuple[float, int, int, int, int, str]] = []


def _recording(path, count, degree, file_bytes, what=""):
    ROWS.append((limits.gaussian_bytes(count, degree) / max(file_bytes, 1), count, degree, file_bytes,
                 limits.gaussian_bytes(count, degree), str(path)))
    return limits.check_expansion(path, count, degree, file_bytes, what)


def _synthetic(n: int, folder: Path) -> list[Path]:
    rng = np.random.default_rng(0)
    g = Gaussians(rng.normal(0, 1, (n, 3)), np.full((n, 3), -4.0), np.tile([1.0, 0, 0, 0], (n, 1)),
                  np.full(n, -2.2), np.concatenate([rng.normal(0, 0.5, (n, 1, 3)), np.zeros((n, 15, 3))], axis=1))
    sog.save(g, folder / "sog" / "meta.json")
    spz.save(g, folder / "v4.spz")
    spz.save(g, folder / "v2.spz", 2)
    return [folder / "sog" / "meta.json", folder / "v4.spz", folder / "v2.spz"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data" / "splats")
    parser.add_argument("--synthetic", type=int, default=50_000)
    args = parser.parse_args()
    for module in (sog, spz, gltf):
        module.check_expansion = _recording
    files = [p for p in sorted(args.data.rglob("*")) if p.is_file() and p.name != "lod-meta.json"
             and p.suffix in (".spz", ".ply", ".splat", ".sog", ".glb", ".gltf") or p.name == "meta.json"]
    with tempfile.TemporaryDirectory() as tmp:
        if args.synthetic:
            files += _synthetic(args.synthetic, Path(tmp))
        for path in files:
            before = len(ROWS)
            splat_io.load(path)
            if len(ROWS) == before:
                print(f"{path}: not checked (an uncompressed format, bounded by its size)")
    print(f"{'bytes decoded / read':>21} {'Gaussians':>10} {'SH':>3} {'file bytes':>11} {'declared':>11}  file")
    for ratio, count, degree, size, declared, path in sorted(ROWS):
        print(f"{ratio:21.2f} {count:10d} {degree:3d} {size:11d} {declared:11d}  {path}")
    print(f"bound: formats_common.limits.MAX_EXPANSION = {limits.MAX_EXPANSION}")


if __name__ == "__main__":
    main()
