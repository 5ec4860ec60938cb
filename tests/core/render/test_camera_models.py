"""Orthographic and panoramic cameras: the native renderer (`addon.core.render.renderer`) against
the float64 reference (tests/reference.py, `camera_model_project`) on random scenes with fresh
seeds, and independent checks of the panoramas (a cube map of six pinhole renders resampled; the
equirectangular seam; the poles).

Tolerances, per Gaussian (u = 1e-5, s = |mean| + |t| as in tests/checks.py): depth u s; xy
u (|xy| + fx + fy) pixels (the mapping's angles are computed in double and rounded once to float);
conic u cond lmax (inverting amplifies rounding by the condition number); opacity 1e-5 + u cond
opacity (antialiasing's factor is a ratio of determinants); rgb 1e-5.
Images: tests/checks.py's (1e-4 on rgb and alpha, ambiguous pixels left out)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from addon.core.cameras import Camera
from addon.core.render import renderer as api
from tests import reference as ref
from tests.checks import assert_images_match
from tests.scenes import random_camera, random_gaussians, random_mesh_layer, random_scene

UNIT = 1e-5
SIZES = [(95, 77), (83, 61), (64, 49), (96, 80), (71, 33)]
EQUIRECT_FULL = (-math.pi, math.pi, -math.pi / 2, math.pi / 2)
PANORAMAS = {
    "equirect": ("EQUIRECTANGULAR", EQUIRECT_FULL),
    "equirect_range": ("EQUIRECTANGULAR", (-1.9, 1.2, -0.7, 1.1)),
    "fisheye_equidistant": ("FISHEYE_EQUIDISTANT", (math.radians(220),)),
    "fisheye_equisolid": ("FISHEYE_EQUISOLID", (8.0, math.radians(180), 36.0, 27.0)),
    "mirrorball": ("MIRRORBALL", ()),
    "fisheye_polynomial": ("FISHEYE_LENS_POLYNOMIAL",  # Blender's default coefficients
                           (-1.1735e-05, -0.019989, -3.3525e-06, 3.0993e-06, -2.6065e-08,
                            math.radians(36), 36.0, 27.0)),  # an image circle in the frame
    "cubemap_face": ("EQUIANGULAR_CUBEMAP_FACE", ()),
    "central_cylindrical": ("CENTRAL_CYLINDRICAL", (-math.pi, math.pi, -1.0, 1.0)),
    "central_cylindrical_range": ("CENTRAL_CYLINDRICAL", (-1.3, 1.9, -0.6, 1.4)),
}
WRAPPING = {"EQUIRECTANGULAR": EQUIRECT_FULL, "CENTRAL_CYLINDRICAL": PANORAMAS[
    "central_cylindrical"][1]}  # the panoramas with a seam (360 degrees of longitude)


def _size(rng):
    return SIZES[rng.integers(len(SIZES))]


def ortho_camera(rng, width, height) -> Camera:
    """A random view of the scene, orthographic: 0.8..1.6 of the scene's 5-unit width."""
    base = random_camera(rng, width, height)
    fx = width / (5.0 * rng.uniform(0.8, 1.6))
    return dataclasses.replace(base, model="ORTHO", fx=fx, fy=fx * rng.uniform(0.9, 1.1))


def panorama_camera(rng, width, height, model, params, *, inside=True) -> Camera:
    """A panoramic camera at a random place inside the cloud (or 6 units out), randomly turned,
    with a small random shift. The lens polynomial's (Blender's default lens: 36 degrees) looks
    at the cloud from outside."""
    inside = inside and model != "FISHEYE_LENS_POLYNOMIAL"
    base = random_camera(rng, width, height, distance=rng.uniform(0.3, 1.5) if inside else 6.0)
    shift_x, shift_y = rng.uniform(-0.05, 0.05, 2)
    return Camera(base.world_to_camera, width, height, -shift_x * width, height * (1 + shift_y),
                  width, height, model=model, params=params)


def _conic_eigen(conic: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each conic's largest eigenvalue and condition number (1 for the wrapping panoramas'
    bands, conic (0, 0, cc))."""
    a, b, c = conic.T
    half = (a + c) / 2
    disc = np.sqrt(np.maximum(0.0, half ** 2 - (a * c - b * b)))
    lmax, lmin = half + disc, np.maximum(half - disc, 1e-300)
    band = valid & (a == 0) & (b == 0)
    return lmax, np.where(band, 1.0, lmax / lmin)


def assert_projection_close(got, want, gaussians, camera):
    valid = want["valid"]
    np.testing.assert_array_equal(got.valid, valid, "valid differs")
    assert valid.mean() > 0.15
    means = np.asarray(gaussians.means, np.float64)
    s = np.linalg.norm(means, axis=1) + np.linalg.norm(camera.world_to_camera[:3, 3])
    lmax, cond = _conic_eigen(want["conic"], valid)
    checks = {
        "depth": (np.abs(got.depth - want["depth"]), UNIT * s),
        "xy": (np.abs(got.xy - want["xy"]),
               UNIT * (np.abs(want["xy"]) + camera.fx + camera.fy)),
        "conic": (np.abs(got.conic - want["conic"]), (UNIT * cond * lmax)[:, None]),
        # antialiasing scales opacity by sqrt(det) ratios of the 2D covariance, as conditioned
        # as its inverse (a mirrorball's Gaussian 0.06 degrees from straight ahead: cond 1e7)
        "opacity": (np.abs(got.opacity - want["opacity"]), 1e-5 + UNIT * cond * want["opacity"]),
        "rgb": (np.abs(got.rgb - want["rgb"]), 1e-5),
    }
    for name, (err, tol) in checks.items():
        ok = (err <= np.broadcast_to(tol, err.shape)).reshape(len(valid), -1).all(1) | ~valid
        assert ok.all(), (f"{name}: {np.count_nonzero(~ok)} Gaussians out of tolerance, e.g. "
                          f"#{np.flatnonzero(~ok)[0]}: native {getattr(got, name)[~ok][0]} "
                          f"reference {want[name][~ok][0]}")


# ------------------------------------------------------------------------------ orthographic

@pytest.mark.parametrize("degree", [0, 3])
@pytest.mark.parametrize("antialiased", [False, True])
def test_ortho_projection_matches_reference(rng, degree, antialiased):
    width, height = _size(rng)
    gaussians = random_gaussians(rng, 1500, degree)
    camera = ortho_camera(rng, width, height)
    got = api.project(gaussians, camera, antialiased=antialiased, near=-100.0)
    want = ref.project_scene(gaussians, camera, antialiased=antialiased, near=-100.0)
    assert_projection_close(got, want, gaussians, camera)


@pytest.mark.parametrize("layers", ["plain", "mesh+background"])
@pytest.mark.parametrize("antialiased", [False, True])
def test_ortho_render_matches_reference(rng, antialiased, layers):
    width, height = _size(rng)
    gaussians = random_gaussians(rng, 400, 2)
    camera = ortho_camera(rng, width, height)
    options = dict(antialiased=antialiased, near=4.0)  # the near plane cuts through the scene
    if layers != "plain":
        options["background"] = rng.random(3).astype(np.float32)
        options["mesh_rgba"], options["mesh_depth"] = random_mesh_layer(rng, width, height)
    got = api.render(gaussians, camera, **options)
    want = ref.render_scene(gaussians, camera, **options)
    assert 0.05 < want["alpha"].mean()
    assert_images_match(got, want)


def test_ortho_clips_at_near_and_far_even_behind_its_origin(rng):
    gaussians = random_gaussians(rng, 800, 1)
    camera = dataclasses.replace(ortho_camera(rng, 64, 48), far=6.5)
    got = api.project(gaussians, camera, near=-2.0)
    want = ref.project_scene(gaussians, camera, near=-2.0)
    depth = want["depth"][want["valid"]]
    assert depth.min() >= -2.0 and depth.max() <= 6.5
    assert_projection_close(got, want, gaussians, camera)
    # Behind the origin: a camera placed in the middle of the cloud still sees all of it.
    inside = dataclasses.replace(camera, world_to_camera=camera.world_to_camera.copy())
    inside.world_to_camera[2, 3] -= 6.0
    seen = api.project(gaussians, inside, near=-100.0).valid
    assert (api.project(gaussians, inside, near=-100.0).depth[seen] < 0).mean() > 0.3


def test_ortho_sees_every_gaussian_along_its_axis(rng):
    # SH colour depends on the view direction only: the same Gaussians moved anywhere in the
    # image plane keep their colour under ORTHO (not under a pinhole).
    gaussians = random_gaussians(rng, 200, 3)
    camera = ortho_camera(rng, 64, 48)
    moved = dataclasses.replace(gaussians, means=gaussians.means + np.float32(
        camera.world_to_camera[0, :3] * 0.7 + camera.world_to_camera[1, :3] * 0.4))
    a, b = api.project(gaussians, camera, near=-100.0), api.project(moved, camera, near=-100.0)
    np.testing.assert_allclose(a.rgb, b.rgb, atol=2e-6)


def test_ortho_is_not_slower_than_pinhole(rng):
    # Same scene, same image: the orthographic projection runs the same vector code.
    gaussians = random_gaussians(rng, 20000, 1)
    pinhole = random_camera(rng, 160, 120)
    ortho = dataclasses.replace(pinhole, model="ORTHO", fx=160 / 5.0, fy=160 / 5.0)
    api.render(gaussians, pinhole, threads=1)
    timings = {name: min(api.render(gaussians, cam, threads=1).stats["ms_project"]
                         for _ in range(3)) for name, cam in (("pinhole", pinhole), ("ortho", ortho))}
    assert timings["ortho"] < 2.0 * timings["pinhole"] + 1.0, timings  # not a benchmark: sanity


# ------------------------------------------------------------------------------- panoramas

@pytest.mark.parametrize("kind", list(PANORAMAS))
@pytest.mark.parametrize("antialiased", [False, True])
def test_panorama_projection_matches_reference(rng, kind, antialiased):
    width, height = _size(rng)
    gaussians = random_gaussians(rng, 1500, 3, radius=4.0)
    camera = panorama_camera(rng, width, height, *PANORAMAS[kind])
    got = api.project(gaussians, camera, antialiased=antialiased)
    want = ref.project_scene(gaussians, camera, antialiased=antialiased)
    assert_projection_close(got, want, gaussians, camera)


@pytest.mark.parametrize("kind", list(PANORAMAS))
@pytest.mark.parametrize("layers", ["plain", "mesh+background"])
def test_panorama_render_matches_reference(rng, kind, layers):
    # Near a mapping's singular directions (a cube face's sides, a mirrorball's rim) a Gaussian
    # can stretch into a conic of condition 1e4 or more (once in about 500 scenes), whose
    # float32 rounding moves its alpha by more than the images' 1e-4: the projection test holds
    # such conics to their conditioning; this one draws again until there is none.
    for _ in range(20):
        width, height = _size(rng)
        gaussians = random_gaussians(rng, 400, 1, radius=4.0)
        camera = panorama_camera(rng, width, height, *PANORAMAS[kind])
        projected = ref.project_scene(gaussians, camera)
        if _conic_eigen(projected["conic"], projected["valid"])[1][projected["valid"]].max() < 1e4:
            break
    options = {}
    if layers != "plain":
        options["background"] = rng.random(3).astype(np.float32)
        options["mesh_rgba"], options["mesh_depth"] = random_mesh_layer(
            rng, width, height, depth_range=(0.5, 5.0))
    got = api.render(gaussians, camera, **options)
    want = ref.render_scene(gaussians, camera, **options)
    assert 0.05 < want["alpha"].mean()
    assert_images_match(got, want)


@pytest.mark.parametrize("model", list(WRAPPING))
def test_seam_and_poles_match_reference(rng, model):
    # Large Gaussians all around the camera: many straddle the seam, some cover a pole (bands).
    # About 1 scene in 400 has no band: drawn again (the same generator) until it has one.
    for _ in range(20):
        gaussians = random_gaussians(rng, 300, 1, radius=3.0)
        gaussians.log_scales += np.float32(0.8)
        camera = panorama_camera(rng, 96, 48, model, WRAPPING[model])
        want_proj = ref.project_scene(gaussians, camera)
        band = want_proj["valid"] & (want_proj["conic"][:, 0] == 0)
        if band.sum() >= 1:
            break
    assert band.sum() >= 1
    copies = want_proj["copies"]
    reach = copies["valid"] & ((copies["xy"][:, 0] < 0) | (copies["xy"][:, 0] > 96))
    assert reach.sum() > 10
    got = api.render(gaussians, camera)
    want = ref.render_scene(gaussians, camera)
    # Gaussians this large put a whole contour (a band's row) at a threshold more often: over
    # 300 scenes the ambiguous pixels were 0.22 % median, 0.52 % at p99, 2.3 % at worst.
    assert_images_match(got, want, max_ambiguous=0.05)


def _yawed(camera: Camera, angle: float) -> Camera:
    """The camera turned by `angle` about its own vertical (y) axis."""
    c, s = math.cos(angle), math.sin(angle)
    turn = np.array([[c, 0, -s, 0], [0, 1, 0, 0], [s, 0, c, 0], [0, 0, 0, 1]])
    return dataclasses.replace(camera, world_to_camera=turn @ camera.world_to_camera)


@pytest.mark.parametrize("model", list(WRAPPING))
def test_panorama_is_continuous_across_the_seam(rng, model):
    # Turning a 360-degree camera by 180 degrees rolls its image by half: Gaussians on the seam
    # in one image are in the middle of the other, so the seam draws them whole.
    gaussians = random_gaussians(rng, 300, 1, radius=3.0)
    camera = panorama_camera(rng, 128, 64, model, WRAPPING[model])
    camera = dataclasses.replace(camera, cx=0.0, cy=64.0)  # no shift: whole-pixel roll
    a = api.render(gaussians, camera).alpha
    b = api.render(gaussians, _yawed(camera, math.pi)).alpha
    assert np.abs(a[:, :3]).max() > 0.1 and np.abs(a[:, -3:]).max() > 0.1  # on the seam
    diff = np.abs(np.roll(b, 64, axis=1) - a)
    # A Gaussian whose alpha at a pixel sits at the 1/255 cut-off falls on either side of it
    # after the turn's float rounding: over 1,000 seeds 6 scenes had one such pixel (up to
    # 0.0035, seed 3489671140 failed CI's run at 0.0021); elsewhere the images agree within 2e-3.
    assert (diff >= 2e-3).mean() <= 1e-3 and diff.max() < 1 / 255


def test_a_gaussian_on_the_pole_is_drawn_all_around(rng):
    up = np.array([0.0, -2.0, 0.0])  # camera frame: y down, so -y is up
    g = random_gaussians(rng, 1, 0)
    g = dataclasses.replace(g, means=up[None].astype(np.float32),
                            log_scales=np.full((1, 3), math.log(0.2), np.float32),
                            opacity_logits=np.array([4.0], np.float32))
    camera = Camera(np.eye(4), 64, 32, 0, 32, 64, 32, model="EQUIRECTANGULAR",
                    params=EQUIRECT_FULL)
    alpha = api.render(g, camera).alpha
    assert (alpha[0] > 0.5).all()  # the top row, every column
    assert (alpha[-8:] == 0).all()
    want = ref.render_scene(g, camera)
    assert_images_match(api.render(g, camera), want)


# The faces see 120 degrees, not 90: every Gaussian that reaches a pixel a face is sampled at
# (within 45 degrees of its axis, 55 at the corners) then has its mean inside the face's view,
# away from the pinhole's guard band, which would distort it.
FACE_TAN = math.tan(math.radians(60))


def _direction_to_face_pixel(d: np.ndarray, face: int, size: int):
    """Face cameras of the cube map: 0 +z, 1 -z, 2 +x, 3 -x, 4 +y, 5 -y (camera frame)."""
    rot = _FACES[face]
    q = d @ rot.T
    f = size / 2 / FACE_TAN
    return f * q[:, 0] / q[:, 2] + size / 2, f * q[:, 1] / q[:, 2] + size / 2


def _face_rotations():
    def look(forward, down):
        forward, down = np.asarray(forward, float), np.asarray(down, float)
        return np.stack([np.cross(down, forward), down, forward])
    return [look((0, 0, 1), (0, 1, 0)), look((0, 0, -1), (0, 1, 0)), look((1, 0, 0), (0, 1, 0)),
            look((-1, 0, 0), (0, 1, 0)), look((0, 1, 0), (0, 0, -1)),
            look((0, -1, 0), (0, 0, 1))]


_FACES = _face_rotations()


def _bilinear(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    h, w = image.shape[:2]
    x, y = np.clip(x - 0.5, 0, w - 1), np.clip(y - 0.5, 0, h - 1)
    x0, y0 = np.minimum(np.floor(x).astype(int), w - 2), np.minimum(np.floor(y).astype(int), h - 2)
    fx, fy = x - x0, y - y0
    if image.ndim == 3:
        fx, fy = fx[:, None], fy[:, None]
    return ((1 - fx) * (1 - fy) * image[y0, x0] + fx * (1 - fy) * image[y0, x0 + 1]
            + (1 - fx) * fy * image[y0 + 1, x0] + fx * fy * image[y0 + 1, x0 + 1])


def cube_map_equirect(gaussians, world_to_camera, width, height, face_size):
    """An independent equirectangular image: six pinhole renders about the cube's axes (the pinhole path,
    held against the reference elsewhere) resampled bilinearly at each pixel's direction."""
    faces = []
    for rot in _FACES:
        w2c = np.eye(4)
        w2c[:3, :3] = rot
        f, c = face_size / 2 / FACE_TAN, face_size / 2
        cam = Camera(w2c @ world_to_camera, f, f, c, c, face_size, face_size)
        result = api.render(gaussians, cam, antialiased=True)
        faces.append(np.concatenate([result.rgb, result.alpha[..., None]], -1))
    cols, rows = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    lon = (cols / width) * 2 * math.pi - math.pi
    lat = math.pi / 2 - (rows / height) * math.pi
    d = np.stack([np.cos(lat) * np.sin(lon), -np.sin(lat), np.cos(lat) * np.cos(lon)], -1)
    d = d.reshape(-1, 3)
    face_of = np.select([np.abs(d[:, 2]) >= np.abs(d).max(1), np.abs(d[:, 0]) >= np.abs(d).max(1)],
                        [np.where(d[:, 2] > 0, 0, 1), np.where(d[:, 0] > 0, 2, 3)],
                        np.where(d[:, 1] > 0, 4, 5))
    out = np.zeros((len(d), 4))
    for face in range(6):
        at = face_of == face
        x, y = _direction_to_face_pixel(d[at], face, face_size)
        out[at] = _bilinear(faces[face], x, y)
    return out.reshape(height, width, 4)


def _small_gaussians_all_around(rng, n, angle):
    """`n` Gaussians 3 to 6 units from the origin in every direction within 60 degrees of the
    equator (nearer the poles the equirectangular linearisation is poor; the poles have their
    own test), each about `angle` radians across (anisotropic)."""
    longitude = rng.uniform(-np.pi, np.pi, n)
    latitude = np.arcsin(rng.uniform(-1.0, 1.0, n) * np.sin(np.radians(60.0)))
    direction = np.stack([np.cos(latitude) * np.sin(longitude), -np.sin(latitude),
                          np.cos(latitude) * np.cos(longitude)], axis=1)
    means = direction * rng.uniform(3.0, 6.0, (n, 1))
    g = random_gaussians(rng, n, 1)
    size = angle * rng.uniform(0.8, 1.2, (n, 1)) * np.linalg.norm(means, axis=1, keepdims=True)
    return dataclasses.replace(g, means=means.astype(np.float32), log_scales=(
        np.log(size) + rng.normal(scale=0.2, size=(n, 3))).astype(np.float32))


def _cube_map_error(gaussians, width):
    """Relative L1 error of the equirectangular alpha against the resampled cube map, and of
    the colour."""
    height = width // 2
    camera = Camera(np.eye(4), width, height, 0, height, width, height,
                    model="EQUIRECTANGULAR", params=EQUIRECT_FULL)
    direct = api.render(gaussians, camera, antialiased=True)
    resampled = cube_map_equirect(gaussians, np.eye(4), width, height, face_size=width * 5 // 4)
    alpha_err = np.abs(direct.alpha - resampled[..., 3]).sum() / direct.alpha.sum()
    rgb_err = np.abs(direct.rgb - resampled[..., :3]).sum() / direct.rgb.sum()
    return alpha_err, rgb_err, direct.alpha.mean()


def test_equirectangular_agrees_with_a_resampled_cube_map(rng):
    # Each image linearises a Gaussian about its mean (the equirectangular mapping, the pinhole
    # faces up to 55 degrees off their axes), so the two agree to first order in the Gaussians'
    # angular size: halving it (and the pixels with it, so that the 0.3 px^2 dilation, which
    # differs between the images' pixels, stays as small; antialiased, so that it keeps their
    # mass) must roughly halve the difference. Measured over 60 seeds: 8.1-13.6 % at 2.7
    # degrees, 3.8-5.4 % at 1.15 (relative L1 of alpha and of colour), ratio at most 0.49.
    seed = int(rng.integers(1 << 31))
    errors = {}
    for angle, width in ((0.047, 512), (0.02, 1024)):
        g = _small_gaussians_all_around(np.random.default_rng(seed), 60, angle)
        errors[angle] = _cube_map_error(g, width)
    print("cube map relative L1 error (alpha, rgb, coverage):", errors)
    (big_alpha, _, covered), (small_alpha, small_rgb, _) = errors[0.047], errors[0.02]
    assert covered > 0.01
    assert small_alpha < 0.09 and small_rgb < 0.09, errors
    assert small_alpha < 0.7 * big_alpha, errors


def test_panorama_depth_is_the_distance(rng):
    gaussians, _ = random_scene(rng, 300, 64, 32, 0)
    camera = panorama_camera(rng, 64, 32, "EQUIRECTANGULAR", EQUIRECT_FULL, inside=False)
    got = api.project(gaussians, camera)
    centre = camera.centre
    distance = np.linalg.norm(gaussians.means.astype(np.float64) - centre, axis=1)
    np.testing.assert_allclose(got.depth[got.valid], distance[got.valid], rtol=1e-6)


def test_training_refuses_other_cameras(rng):
    from addon.core import native
    gaussians = random_gaussians(rng, 10, 0)
    camera = ortho_camera(rng, 32, 24)
    h, w = camera.height, camera.width
    with pytest.raises(ValueError, match="pinhole"):
        native.render_train(gaussians, camera, None, np.empty((h, w, 3), np.float32),
                            np.empty((h, w), np.float32), np.empty((h, w), np.float32), None,
                            None, None, sh_degree=0, near=0.01, antialiased=False, threads=1)


def test_bad_model_parameters_are_refused(monkeypatch):
    with pytest.raises(ValueError, match="parameters"):
        Camera(np.eye(4), 10, 10, 0, 10, 10, 10, model="EQUIRECTANGULAR", params=(1.0,))
    with pytest.raises(ValueError, match="model"):
        Camera(np.eye(4), 10, 10, 0, 10, 10, 10, model="CUBE")
    # A model code the native side does not know is refused there too.
    from addon.core import native
    camera = Camera(np.eye(4), 10, 10, 5, 5, 10, 10)
    real_args = native.camera_args

    def unknown_model(camera):
        viewmat, intrinsics, w, h = real_args(camera)
        intrinsics[4] = 17
        return viewmat, intrinsics, w, h
    monkeypatch.setattr(native, "camera_args", unknown_model)
    with pytest.raises(ValueError, match="model"):
        api.project(random_gaussians(np.random.default_rng(0), 3, 0), camera)


# --------------------------------------------------------------------------- depth of field

@pytest.mark.parametrize("model", ["PINHOLE", "ORTHO"])
@pytest.mark.parametrize("antialiased", [False, True])
def test_depth_of_field_matches_reference(rng, model, antialiased):
    width, height = _size(rng)
    gaussians = random_gaussians(rng, 800, 2)
    camera = random_camera(rng, width, height) if model == "PINHOLE" else \
        ortho_camera(rng, width, height)
    # (an orthographic camera's aperture is 1 / (2 f-stop) world units: wider)
    low, high = (0.05, 0.4) if model == "PINHOLE" else (0.3, 1.0)
    camera = dataclasses.replace(camera, aperture=float(rng.uniform(low, high)),
                                 focus=float(rng.uniform(4.0, 8.0)))
    near = 0.01 if model == "PINHOLE" else 0.5  # (positive depths: an expected depth near 0
    got = api.project(gaussians, camera, antialiased=antialiased, near=near)  # has no rtol)
    want = ref.project_scene(gaussians, camera, antialiased=antialiased, near=near)
    assert_projection_close(got, want, gaussians, camera)
    sharp = api.project(gaussians, dataclasses.replace(camera, aperture=0.0), near=near,
                        antialiased=antialiased)
    # Blurred: a Gaussian widened by a Gaussian has a smaller inverse covariance (Loewner order),
    # so no diagonal entry of the conic grows, and a visible share shrinks by 1 % or more (the
    # smallest share over 300 seeds of this scene was 0.10; with no blur it is 0).
    both = got.valid & sharp.valid
    assert np.all(got.conic[both, 0] <= sharp.conic[both, 0] * (1 + 1e-5))
    assert (got.conic[both, 0] < 0.99 * sharp.conic[both, 0]).mean() > 0.05
    image = api.render(gaussians, camera, antialiased=antialiased, near=near)
    # Blurred splats are wide, so more pixels sit at an alpha threshold (ambiguous in float32):
    # over 150 seeds up to 0.9 % of an orthographic view (median 0.34 %), hence 3 %.
    assert_images_match(image, ref.render_scene(gaussians, camera, antialiased=antialiased,
                                                near=near), max_ambiguous=0.03)


def test_depth_of_field_off_is_bit_for_bit_the_sharp_render(rng):
    gaussians, camera = random_scene(rng, 500, 64, 48, 1)
    a = api.render(gaussians, camera)
    b = api.render(gaussians, dataclasses.replace(camera, aperture=0.0, focus=3.0))
    assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.alpha, b.alpha)


def test_depth_of_field_is_refused_for_panoramas_and_training():
    with pytest.raises(ValueError, match="depth of field"):
        Camera(np.eye(4), 10, 10, 0, 10, 10, 10, model="MIRRORBALL", aperture=0.1)


@pytest.mark.parametrize("kind", ["fisheye_equidistant", "fisheye_equisolid", "mirrorball",
                                  "fisheye_polynomial"])
def test_nothing_is_drawn_outside_the_image_circle(rng, kind):
    # Cycles traces no ray there: a composite keeps the mesh layer's pixels bit for bit, a
    # splat layer is empty; inside, the splats are drawn.
    from addon.core.cameras import image_coverage
    from addon.core.render.composite import compose, splat_layer
    gaussians = random_gaussians(rng, 400, 1, radius=4.0)
    gaussians.log_scales += np.float32(1.0)  # large: they would spill over the circle's edge
    camera = panorama_camera(rng, 64, 40, *PANORAMAS[kind])
    mesh_rgba, mesh_depth = random_mesh_layer(rng, 64, 40, depth_range=(0.5, 5.0))
    outside = ~image_coverage(camera)
    assert 0.1 < outside.mean() < 0.6
    alone = api.render(gaussians, camera)
    assert alone.alpha[outside].max() > 0.1  # the renderer alone does draw there
    for space in ("SRGB", "LINEAR"):
        result = compose(gaussians, camera, mesh_rgba, mesh_depth, color_space=space)
        assert np.array_equal(result.rgba[outside], mesh_rgba[outside])
        assert np.abs(result.rgba[~outside] - mesh_rgba[~outside]).max() > 0.1
    layer = splat_layer(gaussians, camera)
    assert (layer.rgba[outside] == 0).all() and layer.rgba[~outside, 3].max() > 0.1
