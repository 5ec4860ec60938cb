"""Small files that ask for gigabytes (issue 33), made by small functions rather than checked in
as blobs: the seeds scripts/fuzz.py adds to its campaigns (so the next amplification is found
from these), and the inputs the hardening tests build. Each returns {relative path: bytes}.

- `sog_bomb`: a SOG (folder, or a `.sog` bundle) whose meta.json declares 10M Gaussians over
  uniform 3162x3162 lossless WebPs of about 460 bytes each (a few KB in all);
- `lod_bomb`: a streamed-SOG set whose environment chunk is that SOG;
- `glb_instances`: a `.glb` whose one primitive (its SH coefficients sharing one accessor, as a
  file made to be small would) is shown by `nodes` nodes;
- `spz_gzip_bomb`: a gzip `.spz` (v2) declaring 10M points, its stream all zeros;
- `sequence_of_bombs`: a folder of `frames` numbered `.sog` frames, each a `sog_bomb`;
- `colmap_long_name`: a COLMAP model (bin or txt) with an image named by 300 characters;
- `attribute_arrays`: Blender 5.3 splat attributes, one or two of them of a hostile dtype or
  shape (arrays, not files: scripts/fuzz.py's `attribute_campaign` runs them in-process).
"""

from __future__ import annotations

import io
import json
import struct
import tempfile
import zipfile
import zlib
from pathlib import Path

import numpy as np

SIDE = 3162  # 3162^2 = 9,998,244 pixels: one per Gaussian
COUNT = 10_000_000 - 1756  # what SIDE x SIDE holds


def _webp(alpha: int) -> bytes:
    from addon.core.formats_common import webp
    image = np.zeros((SIDE, SIDE, 4), np.uint8)
    image[..., 3] = alpha
    with tempfile.TemporaryDirectory() as tmp:
        webp.write_rgba(Path(tmp) / "i.webp", image)
        return (Path(tmp) / "i.webp").read_bytes()


def sog_bomb(bundle: bool = False, name: str = "a.sog") -> dict[str, bytes]:
    """A SOG declaring COUNT Gaussians in a few KB: meta.json + five uniform images, or a bundle
    `name` holding them."""
    plain, quats = _webp(255), _webp(252)  # quats' alpha: 252 + the largest component's index
    meta = {"version": 2, "count": COUNT, "antialias": False,
            "means": {"mins": [0, 0, 0], "maxs": [1, 1, 1], "files": ["means_l.webp", "means_u.webp"]},
            "scales": {"codebook": [-4.0] * 256, "files": ["scales.webp"]},
            "quats": {"files": ["quats.webp"]},
            "sh0": {"codebook": [0.0] * 256, "files": ["sh0.webp"]}}
    files = {"meta.json": json.dumps(meta).encode(), "means_l.webp": plain, "means_u.webp": plain,
             "quats.webp": quats, "scales.webp": plain, "sh0.webp": plain}
    if not bundle:
        return files
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_STORED) as archive:
        for member, data in files.items():
            archive.writestr(member, data)
    return {name: out.getvalue()}


def lod_bomb() -> dict[str, bytes]:
    """A streamed-SOG set of one small chunk, its environment a `sog_bomb`."""
    from addon.core.formats import sog
    from addon.core.gaussians import Gaussians
    with tempfile.TemporaryDirectory() as tmp:
        g = Gaussians(np.zeros((4, 3)), np.full((4, 3), -3.0), np.tile([1.0, 0, 0, 0], (4, 1)),
                      np.zeros(4), np.zeros((4, 1, 3)))
        sog.save(g, Path(tmp) / "meta.json")
        files = {f"c0/{p.name}": p.read_bytes() for p in Path(tmp).iterdir()}
    files.update({f"env/{name}": data for name, data in sog_bomb().items()})
    files["lod-meta.json"] = json.dumps({
        "version": 1, "lodLevels": 1, "filenames": ["c0/meta.json"], "environment": "env/meta.json",
        "tree": {"lods": {"0": {"file": 0, "offset": 0, "count": 4}}}}).encode()
    return files


def glb_instances(nodes: int = 166, count: int = 60_000, degree: int = 3) -> dict[str, bytes]:
    """A `.glb`: one primitive of `count` Gaussians whose SH attributes all share one accessor,
    shown by `nodes` nodes side by side."""
    from addon.core.formats import gltf
    from addon.core.gaussians import Gaussians
    rng = np.random.default_rng(33)
    g = Gaussians(rng.normal(0, 1, (count, 3)), np.full((count, 3), -3.0), np.tile([1.0, 0, 0, 0], (count, 1)),
                  np.zeros(count), np.zeros((count, (degree + 1) ** 2, 3)))
    document, binary = gltf._document(g.with_degree(0))  # noqa: SLF001 - the writer's own layout
    attributes = document["meshes"][0]["primitives"][0]["attributes"]
    for name in gltf.attribute_names(degree):
        attributes[name] = attributes[gltf.attribute_names(0)[0]]
    document["nodes"] = [{"mesh": 0, "translation": [float(i), 0.0, 0.0]} for i in range(nodes)]
    document["scenes"] = [{"nodes": list(range(nodes))}]
    text = json.dumps(document).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<II", len(text), gltf.CHUNK_JSON) + text
    body += struct.pack("<II", len(binary), gltf.CHUNK_BIN) + binary
    return {"a.glb": struct.pack("<III", gltf.GLB_MAGIC, 2, 12 + len(body)) + body}


def spz_gzip_bomb(points: int = 10_000_000, version: int = 2, degree: int = 0) -> dict[str, bytes]:
    """A gzip `.spz` declaring `points` points, its arrays all zeros (compressed in pieces)."""
    from addon.core.formats import spz
    total = sum(spz._stream_sizes(points, version, degree))  # noqa: SLF001
    out = zlib.compressobj(9, zlib.DEFLATED, 16 + 15)
    parts = [out.compress(struct.pack("<IIIBBBB", spz.MAGIC, version, points, degree, 12, 0, 0))]
    piece = bytes(1 << 22)
    for done in range(0, total, len(piece)):
        parts.append(out.compress(piece[:min(len(piece), total - done)]))
    return {"a.spz": b"".join(parts) + out.flush()}


def sequence_of_bombs(frames: int = 2) -> dict[str, bytes]:
    """A folder `seq` of `frames` numbered `.sog` frames, each a `sog_bomb`."""
    bomb = sog_bomb(bundle=True)["a.sog"]
    return {f"seq/walk_{i:04d}.sog": bomb for i in range(1, frames + 1)}


def colmap_long_name(fmt: str = ".bin", model: dict[str, bytes] | None = None) -> dict[str, bytes]:
    """A COLMAP model (scripts/fuzz.py's small one by default) whose first image is named by 300
    characters (binary names end at a NUL, so the record just grows)."""
    if model is None:
        from scripts import fuzz
        model = fuzz._colmap_model(fmt, np.random.default_rng(33))  # noqa: SLF001
    name = ("a" * 296 + ".png").encode()
    return {file: data.replace(b"sub/001.png", name) if file.startswith("images") else data
            for file, data in model.items()}


def attribute_arrays(rnd, n: int = 6, degree: int = 1) -> dict:
    """Blender 5.3 splat attributes (name -> array) with one or two of them replaced by what a
    script or a damaged file may hand over: object, dict, structured, string, complex or ragged
    arrays, another shape, huge or non-finite numbers (the sixth shape: not a file)."""
    from addon.core.blender_splats import attributes
    from addon.core.gaussians import Gaussians
    rng = np.random.default_rng(rnd.randrange(1 << 30))
    g = Gaussians(rng.normal(0, 1, (n, 3)), rng.normal(-3, 1, (n, 3)), rng.normal(0, 1, (n, 4)),
                  rng.normal(0, 2, n), rng.normal(0, 0.5, (n, (degree + 1) ** 2, 3)))
    arrays: dict = dict(attributes.attributes_from_gaussians(g))
    for name in rnd.sample(sorted(arrays), rnd.choice((1, 1, 2))):
        good = arrays[name]
        arrays[name] = rnd.choice([
            lambda: np.array([object()] * good.size, dtype=object),
            lambda: np.array([{"x": 1}] * len(good), dtype=object),
            lambda: np.zeros(len(good), dtype=[("a", "f4"), ("b", "f4")]),
            lambda: good.astype(str), lambda: good.astype("S4"), lambda: good.astype(np.complex64),
            lambda: [[1.0, 2.0], [3.0]], lambda: good.reshape(-1, 1), lambda: good[:-1],
            lambda: good.ravel(), lambda: np.full_like(good, np.nan), lambda: np.full(good.shape, 1e300),
            lambda: good.astype(np.int64) * 2**40, lambda: good.astype(bool), lambda: np.zeros((0, 3)),
            lambda: None, lambda: "position", lambda: good.T,
        ])()
    return arrays
