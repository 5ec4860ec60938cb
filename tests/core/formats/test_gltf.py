"""glTF KHR_gaussian_splatting (.glb / .gltf): the written structure against the extension's rules
and JSON schema, bit-exact round trips where the format is float, files assembled here by hand
(interleaved and quantised accessors, node transforms, several primitives), and malformed files."""

from __future__ import annotations

import base64
import json
import math
import struct
from pathlib import Path

import numpy as np
import pytest

from addon.core import splat_io
from addon.core.formats import gltf, ply
from addon.core.formats_common.errors import SplatFileError
from addon.core.formats_common.frames import rdf_to_rub
from addon.core.gaussians import Gaussians
from addon.core.render.renderer import render
from scenes import playbot_camera
from addon.core.transform import covariances, transform_gaussians

EXT = "KHR_gaussian_splatting"
P = EXT + ":"
FLOAT, BYTE, UBYTE, SHORT, USHORT = 5126, 5120, 5121, 5122, 5123
# The extension object's JSON schema (schema/mesh.primitive.KHR_gaussian_splatting.schema.json,
# its own properties; the glTFProperty base adds only `extensions` and `extras`).
EXTENSION_SCHEMA = {
    "type": "object",
    "properties": {
        "kernel": {"type": "string"},
        "colorSpace": {"type": "string"},
        "projection": {"type": "string"},
        "sortingMethod": {"type": "string"},
        "extensions": {"type": "object"},
        "extras": {},
    },
    "required": ["colorSpace", "kernel"],
}
# The attribute table of the extension: semantic -> (accessor type, allowed component types).
ATTRIBUTE_RULES = {
    "POSITION": ("VEC3", {FLOAT}),
    P + "ROTATION": ("VEC4", {FLOAT, BYTE, SHORT}),
    P + "SCALE": ("VEC3", {FLOAT, UBYTE, USHORT}),
    P + "OPACITY": ("SCALAR", {FLOAT, UBYTE, USHORT}),
    "COLOR_0": ("VEC4", {FLOAT, UBYTE, USHORT}),
}


def random_gaussians(rng: np.random.Generator, n: int, degree: int) -> Gaussians:
    k = (degree + 1) ** 2
    return Gaussians(rng.uniform(-5, 5, (n, 3)), rng.uniform(-8, 1, (n, 3)), rng.normal(size=(n, 4)),
                     rng.normal(0, 4, n), rng.normal(0, 0.5, (n, k, 3)))


def unit(q: np.ndarray) -> np.ndarray:
    q = q.astype(np.float64)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-x.astype(np.float64)))


def split_glb(data: bytes) -> tuple[dict, bytes]:
    magic, version, length = struct.unpack_from("<4sII", data)
    assert (magic, version, length) == (b"glTF", 2, len(data))
    json_length, json_kind = struct.unpack_from("<II", data, 12)
    assert json_kind == 0x4E4F534A and json_length % 4 == 0
    text = data[20:20 + json_length]
    assert text == text.rstrip(b" ") + b" " * (len(text) - len(text.rstrip(b" ")))  # space padded
    bin_length, bin_kind = struct.unpack_from("<II", data, 20 + json_length)
    assert bin_kind == 0x004E4942 and bin_length % 4 == 0
    assert 28 + json_length + bin_length == len(data)
    return json.loads(text), data[28 + json_length:]


def check_structure(document: dict, binary_length: int, degree: int, n: int) -> None:
    """The glTF core rules and the extension's rules a viewer relies on."""
    assert document["asset"]["version"] == "2.0"
    assert EXT in document["extensionsUsed"]
    assert EXT not in document.get("extensionsRequired", [])  # point-cloud fallback stays possible
    assert document["buffers"][0]["byteLength"] == binary_length
    for view in document["bufferViews"]:
        assert view["byteOffset"] % 4 == 0 and view["byteOffset"] + view["byteLength"] <= binary_length
    (primitive,) = document["meshes"][0]["primitives"]
    assert primitive["mode"] == 0
    extension = primitive["extensions"][EXT]
    try:
        import jsonschema
    except ImportError:  # not a project dependency: the same rules by hand
        assert all(key in extension for key in EXTENSION_SCHEMA["required"])
        assert all(isinstance(v, str) for k, v in extension.items() if k not in ("extensions", "extras"))
    else:
        jsonschema.validate(extension, EXTENSION_SCHEMA)
    assert extension["kernel"] == "ellipse" and extension["colorSpace"] == "srgb_rec709_display"
    sh = [f"{P}SH_DEGREE_{band}_COEF_{m}" for band in range(degree + 1) for m in range(2 * band + 1)]
    assert set(primitive["attributes"]) == set(ATTRIBUTE_RULES) | set(sh)
    for name, index in primitive["attributes"].items():
        accessor = document["accessors"][index]
        kind, components = ATTRIBUTE_RULES.get(name, ("VEC3", {FLOAT}))
        assert accessor["type"] == kind and accessor["componentType"] in components, name
        assert accessor["count"] == n
        view = document["bufferViews"][accessor["bufferView"]]
        width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}[kind] * (4 if accessor["componentType"] == FLOAT else 1)
        assert accessor.get("byteOffset", 0) + width * n <= view["byteLength"]
    position = document["accessors"][primitive["attributes"]["POSITION"]]
    assert len(position["min"]) == len(position["max"]) == 3  # required for POSITION


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_glb_structure_and_round_trip(rng: np.random.Generator, tmp_path: Path, degree: int) -> None:
    g = random_gaussians(rng, 333, degree)
    g.opacity_logits[:3] = [30.0, -30.0, 0.0]
    splat_io.save(g, tmp_path / "x.glb")
    document, binary = split_glb((tmp_path / "x.glb").read_bytes())
    check_structure(document, len(binary), degree, 333)
    attributes = document["meshes"][0]["primitives"][0]["attributes"]

    def stored(name: str, width: int) -> np.ndarray:
        accessor = document["accessors"][attributes[name]]
        view = document["bufferViews"][accessor["bufferView"]]
        return np.frombuffer(binary, "<f4", 333 * width, view["byteOffset"]).reshape(333, width)

    # In the file: glTF's y-up frame (half a turn about x), activated scale and opacity, xyzw.
    np.testing.assert_array_equal(stored("POSITION", 3), g.means * [1, -1, -1])
    np.testing.assert_allclose(stored(P + "SCALE", 3), np.exp(g.log_scales.astype(np.float64)), rtol=1e-6)
    np.testing.assert_allclose(stored(P + "OPACITY", 1)[:, 0], sigmoid(g.opacity_logits), rtol=1e-6, atol=1e-30)
    q = unit(g.quats) * [1, 1, -1, -1]
    np.testing.assert_allclose(stored(P + "ROTATION", 4), q[:, [1, 2, 3, 0]], atol=1e-7)
    if degree:
        np.testing.assert_array_equal(stored(f"{P}SH_DEGREE_1_COEF_2", 3), g.sh[:, 3])  # x: even in y, z

    back = splat_io.load(tmp_path / "x.glb")
    np.testing.assert_array_equal(back.means, g.means)
    np.testing.assert_array_equal(back.sh, g.sh)
    np.testing.assert_allclose(back.log_scales, g.log_scales, atol=1e-6)
    np.testing.assert_allclose(np.abs(np.sum(unit(back.quats) * unit(g.quats), axis=1)), 1.0, atol=1e-6)
    np.testing.assert_allclose(sigmoid(back.opacity_logits), sigmoid(g.opacity_logits), atol=6e-8)
    assert back.opacity_logits[0] == pytest.approx(16.6, abs=0.1)  # float32 holds no opacity nearer 1
    assert back.opacity_logits[1] == pytest.approx(-30.0, abs=1e-5)


def test_gltf_text_form_matches_glb(rng: np.random.Generator, tmp_path: Path) -> None:
    g = random_gaussians(rng, 50, 2)
    splat_io.save(g, tmp_path / "x.gltf")
    splat_io.save(g, tmp_path / "x.glb")
    document = json.loads((tmp_path / "x.gltf").read_text())
    assert document["buffers"][0]["uri"].startswith("data:application/octet-stream;base64,")
    a, b = splat_io.load(tmp_path / "x.gltf"), splat_io.load(tmp_path / "x.glb")
    for name, value in a.arrays().items():
        np.testing.assert_array_equal(value, getattr(b, name), err_msg=name)


def test_axis_flip_is_the_half_turn_about_x(rng: np.random.Generator) -> None:
    g = random_gaussians(rng, 64, 3)
    exact = rdf_to_rub(g)
    general = transform_gaussians(g, np.diag([1.0, -1.0, -1.0, 1.0]))  # float64 SH rotation
    np.testing.assert_allclose(exact.sh, general.sh, atol=1e-5)
    np.testing.assert_allclose(exact.means, general.means, atol=1e-6)
    # The same ellipsoids (F R S and F R F S agree: F S F = S for the diagonal flip F).
    np.testing.assert_allclose(covariances(exact), covariances(general), atol=1e-6)
    again = rdf_to_rub(exact)
    for name, value in g.arrays().items():
        np.testing.assert_array_equal(getattr(again, name), value)


def test_playbot_round_trip_renders_identically(shared_data: Path, tmp_path: Path) -> None:
    g = ply.load(shared_data / "splats" / "playbot_125k_sh2.ply")
    gltf.save(g, tmp_path / "playbot.glb")
    back = gltf.load(tmp_path / "playbot.glb")
    camera = playbot_camera()
    a, b = render(back, camera).rgb, render(g, camera).rgb
    assert np.abs(a - b).max() < 1e-5  # measured PSNR 171 dB: float rounding of scale and opacity
    assert (tmp_path / "playbot.glb").stat().st_size < 19_600_000


# ------------------------------------------------------------------------------------------
# Hand-assembled files


def build(tmp_path: Path, accessors: dict[str, tuple[np.ndarray, int, str, bool, int]], *,
          extension: dict | None = None, document_extra: dict | None = None, mode: int = 0,
          nodes: list | None = None, primitives: int = 1, name: str = "x.glb",
          uri: str | None = None) -> Path:
    """A .glb (or .gltf) of one mesh; accessors: semantic -> (data, componentType, type,
    normalized, byteStride or 0). Data is written row by row at `byteStride`."""
    blob, views, acc, attributes = b"", [], [], {}
    for semantic, (data, component, kind, normalized, stride) in accessors.items():
        rows = [np.ascontiguousarray(r).tobytes() for r in data]
        element = len(rows[0]) if rows else 0
        stride = stride or element
        raw = b"".join(r + b"\xAB" * (stride - element) for r in rows)
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(raw),
                      **({"byteStride": stride} if stride != element else {})})
        accessor = {"bufferView": len(views) - 1, "componentType": component, "count": len(data), "type": kind}
        if normalized:
            accessor["normalized"] = True
        acc.append(accessor)
        attributes[semantic] = len(acc) - 1
        blob += raw + b"\0" * ((-len(raw)) % 4)
    primitive = {"attributes": attributes, "mode": mode,
                 "extensions": {EXT: extension or {"kernel": "ellipse", "colorSpace": "srgb_rec709_display"}}}
    document = {"asset": {"version": "2.0"}, "extensionsUsed": [EXT], "scene": 0,
                "scenes": [{"nodes": [0]}], "nodes": nodes or [{"mesh": 0}],
                "meshes": [{"primitives": [primitive] * primitives}], "buffers": [{"byteLength": len(blob)}],
                "bufferViews": views, "accessors": acc, **(document_extra or {})}
    path = tmp_path / name
    if name.endswith(".gltf"):
        document["buffers"][0]["uri"] = uri if uri is not None else "x.bin"
        (tmp_path / "x.bin").write_bytes(blob)
        path.write_text(json.dumps(document))
        return path
    text = json.dumps(document).encode()
    text += b" " * ((-len(text)) % 4)
    path.write_bytes(struct.pack("<4sII", b"glTF", 2, 28 + len(text) + len(blob))
                     + struct.pack("<II", len(text), 0x4E4F534A) + text
                     + struct.pack("<II", len(blob), 0x004E4942) + blob)
    return path


def basic(n: int = 4) -> dict:
    rng = np.random.default_rng(3)
    quats = unit(rng.normal(size=(n, 4)))
    return {
        "POSITION": (rng.normal(size=(n, 3)).astype("<f4"), FLOAT, "VEC3", False, 0),
        P + "ROTATION": (quats[:, [1, 2, 3, 0]].astype("<f4"), FLOAT, "VEC4", False, 0),
        P + "SCALE": (np.full((n, 3), 0.5, "<f4"), FLOAT, "VEC3", False, 0),
        P + "OPACITY": (np.full(n, 0.25, "<f4"), FLOAT, "SCALAR", False, 0),
        P + "SH_DEGREE_0_COEF_0": (rng.normal(size=(n, 3)).astype("<f4"), FLOAT, "VEC3", False, 0),
    }


def test_reads_quantised_interleaved_and_external_buffers(tmp_path: Path) -> None:
    reference = gltf.load(build(tmp_path, basic(), name="ref.glb"))
    attributes = basic()
    rotation = attributes[P + "ROTATION"][0].astype(np.float64)
    attributes[P + "ROTATION"] = (np.round(rotation * 32767).astype("<i2"), SHORT, "VEC4", True, 12)
    attributes[P + "OPACITY"] = (np.full(4, 64, np.uint8), UBYTE, "SCALAR", True, 4)
    attributes[P + "SCALE"] = (np.full((4, 3), 1, np.uint8), UBYTE, "VEC3", False, 8)  # not normalised: 1.0
    attributes["POSITION"] = (attributes["POSITION"][0], FLOAT, "VEC3", False, 20)  # interleaved stride
    for name in ("q.glb", "q.gltf"):
        g = gltf.load(build(tmp_path, attributes, name=name))
        np.testing.assert_array_equal(g.means, reference.means)
        np.testing.assert_allclose(np.abs(np.sum(unit(g.quats) * unit(reference.quats), axis=1)), 1, atol=1e-8)
        np.testing.assert_allclose(sigmoid(g.opacity_logits), 64 / 255, rtol=1e-6)
        np.testing.assert_allclose(g.log_scales, 0.0, atol=1e-7)
    inline = "data:application/octet-stream;base64," + base64.b64encode((tmp_path / "x.bin").read_bytes()).decode()
    assert len(gltf.load(build(tmp_path, attributes, name="i.gltf", uri=inline))) == 4


def test_node_transforms_and_several_primitives(tmp_path: Path) -> None:
    plain = gltf.load(build(tmp_path, basic(), name="plain.glb"))
    moved = gltf.load(build(tmp_path, basic(), name="moved.glb",
                            nodes=[{"children": [1], "translation": [1.0, 2.0, 3.0]}, {"mesh": 0, "scale": [2, 2, 2]}]))
    # glTF (x, y, z) + (1, 2, 3) is our (x, -y, -z) + (1, -2, -3); the scale doubles sizes.
    np.testing.assert_allclose(moved.means, plain.means * 2 + [1.0, -2.0, -3.0], atol=1e-5)
    np.testing.assert_allclose(moved.log_scales, plain.log_scales + math.log(2), atol=1e-6)
    twice = gltf.load(build(tmp_path, basic(), name="twice.glb", primitives=2))
    assert len(twice) == 8


@pytest.mark.parametrize("change, message", [
    (lambda a, e: a.pop(P + "OPACITY"), "missing required attribute"),
    (lambda a, e: a.update({P + "SH_DEGREE_1_COEF_0": (np.zeros((4, 3), "<f4"), FLOAT, "VEC3", False, 0)}),
     "SH degrees must be complete"),
    (lambda a, e: a.update({P + "SCALE": (np.full((4, 3), -1.0, "<f4"), FLOAT, "VEC3", False, 0)}),
     "scales must be >= 0"),
    (lambda a, e: a.update({P + "OPACITY": (np.full(4, 1.5, "<f4"), FLOAT, "SCALAR", False, 0)}), "opacities in"),
    (lambda a, e: a.update({P + "OPACITY": (np.full(3, 0.5, "<f4"), FLOAT, "SCALAR", False, 0)}), "has 3 elements"),
    (lambda a, e: a.update({P + "SCALE": (np.zeros((4, 3), "<i2"), SHORT, "VEC3", False, 0)}), "not allowed"),
    (lambda a, e: a.update({P + "ROTATION": (np.zeros((4, 3), "<f4"), FLOAT, "VEC3", False, 0)}), "expected VEC4"),
    (lambda a, e: e.update(extensions={gltf.SPZ_EXTENSION: {"bufferView": 0}}), "not supported"),
])
def test_bad_primitives(tmp_path: Path, change, message: str) -> None:
    attributes = basic()
    extension = {"kernel": "ellipse", "colorSpace": "srgb_rec709_display"}
    change(attributes, extension)
    path = build(tmp_path, attributes, extension=extension)
    with pytest.raises(SplatFileError, match=message) as error:
        gltf.load(path)
    assert str(path) in str(error.value)


def test_bad_files(tmp_path: Path) -> None:
    good = build(tmp_path, basic()).read_bytes()
    cases = {
        "truncated": (good[:-30], "truncated"),
        "short": (good[:10], "truncated"),
        "magic": (b"glTX" + good[4:], "bad JSON in the glTF document"),
        "version": (good[:4] + struct.pack("<I", 1) + good[8:], "container version 1"),
        "json": (good[:20] + b"}" + good[21:], "bad JSON in the glTF document"),
    }
    for name, (data, message) in cases.items():
        path = tmp_path / f"{name}.glb"
        path.write_bytes(data)
        with pytest.raises(SplatFileError, match=message) as error:
            gltf.load(path)
        assert str(path) in str(error.value)
    with pytest.raises(SplatFileError, match="mode POINTS"):
        gltf.load(build(tmp_path, basic(), mode=4))
    with pytest.raises(SplatFileError, match="requires unsupported extension KHR_gaussian_splatting_compression"):
        gltf.load(build(tmp_path, basic(), document_extra={"extensionsRequired": [gltf.SPZ_EXTENSION]}))
    with pytest.raises(SplatFileError, match="no KHR_gaussian_splatting primitive"):
        gltf.load(build(tmp_path, basic(), nodes=[{}]))
    with pytest.raises(SplatFileError, match="bad data URI"):
        gltf.load(build(tmp_path, basic(), name="u.gltf", uri="data:application/octet-stream;base64,@@@"))
    with pytest.raises(SplatFileError, match="must be a relative path inside"):
        gltf.load(build(tmp_path, basic(), name="v.gltf", uri="/etc/passwd"))


def test_huge_count_is_refused_before_allocating(tmp_path: Path) -> None:
    path = build(tmp_path, basic())
    document, binary = split_glb(path.read_bytes())
    for accessor in document["accessors"]:
        accessor["count"] = 10 ** 12
    text = json.dumps(document).encode()
    text += b" " * ((-len(text)) % 4)
    path.write_bytes(struct.pack("<4sII", b"glTF", 2, 28 + len(text) + len(binary))
                     + struct.pack("<II", len(text), 0x4E4F534A) + text
                     + struct.pack("<II", len(binary), 0x004E4942) + binary)
    with pytest.raises(SplatFileError, match="do not fit|more than the limit"):
        gltf.load(path)


def test_corrupted_files_raise_only_splat_file_errors(rng: np.random.Generator, tmp_path: Path) -> None:
    g = random_gaussians(rng, 9, 1)
    gltf.save(g, tmp_path / "a.glb")
    gltf.save(g, tmp_path / "b.gltf")
    sources = [(tmp_path / "a.glb").read_bytes(), (tmp_path / "b.gltf").read_bytes()]
    alphabet = list(b'0123456789 ,.-"[]{}:eE')
    for i in range(300):
        data = bytearray(sources[i % 2])
        if i % 3 == 0:
            data = data[:rng.integers(0, len(data))]
        json_end = data.find(b'"buffers"') if i % 2 else min(len(data), 2000)
        for _ in range(rng.integers(1, 5) if data else 0):  # JSON-ish bytes in the JSON
            data[rng.integers(0, max(1, min(json_end, len(data))))] = rng.choice(alphabet)
        path = tmp_path / ("fuzz.glb" if i % 2 == 0 else "fuzz.gltf")
        path.write_bytes(bytes(data))
        try:
            gltf.load(path)
        except SplatFileError:
            pass
