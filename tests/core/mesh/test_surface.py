"""Splats to meshes, Blender-free: surface nets, TSDF fusion, the z-buffer and the texture bake
(addon/core/mesh/surface.py, addon/core/mesh/texture.py) on analytic scenes with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from addon.core.mesh import surface as S
from addon.core.mesh import texture as T
from addon.core.cameras import Camera

from scenes import sphere_gaussians


def sphere_depth(camera: Camera, radius: float) -> np.ndarray:
    """Planar depth of a sphere at the origin (inf where missed)."""
    j, i = np.mgrid[0:camera.height, 0:camera.width] + 0.5
    d_cam = np.stack([(i - camera.cx) / camera.fx, (j - camera.cy) / camera.fy,
                      np.ones_like(i)], axis=-1)  # planar z = 1
    rot = camera.world_to_camera[:3, :3]
    d = d_cam @ rot  # world direction (rot.T @ d_cam)
    o = camera.centre
    a = (d * d).sum(-1)
    b = 2 * (d @ o)
    c = o @ o - radius ** 2
    disc = b * b - 4 * a * c
    with np.errstate(invalid="ignore"):
        t = (-b - np.sqrt(disc)) / (2 * a)
    return np.where(disc > 0, t, np.inf).astype(np.float32)


def check_closed_sphere(vertices, faces, radius, tolerance):
    assert S.is_watertight(faces), np.bincount(S.edge_face_counts(faces))
    r = np.linalg.norm(vertices, axis=1)
    assert np.abs(r - radius).max() < tolerance, np.abs(r - radius).max()
    # Outward winding: every face normal points away from the centre, and the volume is right.
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    normal = np.cross(b - a, c - a)
    assert (np.einsum("ij,ij->i", normal, a + b + c) > 0).mean() > 0.99
    volume = S.signed_volume(vertices, faces)
    assert volume == pytest.approx(4 / 3 * np.pi * radius ** 3, rel=0.05)


def test_surface_nets_on_an_analytic_sphere():
    step = 0.05
    ax = np.arange(-1.2, 1.2 + 1e-9, step)
    g = np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), -1)
    field = np.linalg.norm(g, axis=-1) - 0.8
    vertices, faces = S.surface_nets(field, (-1.2, -1.2, -1.2), step)
    check_closed_sphere(vertices, faces, 0.8, 0.25 * step)


def test_surface_nets_closes_a_volume_cut_by_the_grid():
    # Everything inside: the padding closes the box.
    vertices, faces = S.surface_nets(-np.ones((4, 5, 6)), (0, 0, 0), 1.0)
    assert S.is_watertight(faces)
    assert S.signed_volume(vertices, faces) > 0


def test_fibonacci_cameras_look_at_the_centre():
    cams = S.fibonacci_cameras((1, 2, 3), 5.0, 20, 32, 24, fov=40)
    assert len(cams) == 20
    for cam in cams:
        assert np.linalg.norm(cam.centre - [1, 2, 3]) == pytest.approx(5.0)
        c = cam.world_to_camera @ np.array([1, 2, 3, 1.0])
        assert c[0] == pytest.approx(0, abs=1e-9) and c[1] == pytest.approx(0, abs=1e-9)
        assert c[2] == pytest.approx(5.0)


def test_tsdf_fusion_of_synthetic_sphere_depth():
    radius = 1.0
    cams = S.fibonacci_cameras((0, 0, 0), 3.5, 24, 64, 64, fov=50)
    depths = [sphere_depth(c, radius) for c in cams]
    alphas = [np.isfinite(d).astype(np.float32) for d in depths]
    bounds = (np.full(3, -1.3), np.full(3, 1.3))
    volume = S.fuse_tsdf(depths, alphas, cams, bounds, 40)
    vertices, faces = S.extract_surface(volume)
    check_closed_sphere(vertices, faces, radius, volume.grid.voxel)


def test_zbuffer_matches_the_analytic_sphere():
    step = 0.04
    ax = np.arange(-1.2, 1.2 + 1e-9, step)
    g = np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), -1)
    vertices, faces = S.surface_nets(np.linalg.norm(g, axis=-1) - 1.0, (-1.2,) * 3, step)
    cam = Camera.look_at((0.3, -3.0, 0.5), (0, 0, 0), width=48, height=40, fov_x_degrees=50)
    got = S.zbuffer_depth(vertices, faces, cam)
    want = sphere_depth(cam, 1.0)
    both = np.isfinite(got) & np.isfinite(want)
    assert (np.isfinite(got) == np.isfinite(want)).mean() > 0.97  # silhouette pixels may flip
    assert np.abs(got[both] - want[both]).max() < step


def test_splats_to_surface_on_a_sphere_of_gaussians():
    g = sphere_gaussians(1.0, 3000, 0.05)
    result = S.splats_to_surface(g, resolution=40, view_count=24, view_size=64, threads=1)
    voxel = result.volume.grid.voxel
    check_closed_sphere(result.vertices, result.faces, np.median(
        np.linalg.norm(result.vertices, axis=1)), 1.5 * voxel)
    r = np.linalg.norm(result.vertices, axis=1)
    assert abs(np.median(r) - 1.0) < voxel + 2 * 0.05  # the splats' surface is about 1 sigma out


def plane_scene():
    """A 2x2 plane at z = 0 (a 6x6 grid of quads) and one camera looking down at it, whose image
    shows colour (x + 1) / 2, (y + 1) / 2, 0.25 at the world point (x, y, 0)."""
    n = 6
    xs = np.linspace(-1, 1, n + 1)
    gx, gy = np.meshgrid(xs, xs, indexing="ij")
    vertices = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    cam = Camera.look_at((0, 0, 3), (0, 0, 0), (0, 1, 0), width=96, height=96, fov_x_degrees=60)
    j, i = np.mgrid[0:96, 0:96] + 0.5
    ray = np.stack([(i - cam.cx) / cam.fx, (j - cam.cy) / cam.fy, np.ones_like(i)], -1)
    world = cam.centre + 3.0 * (ray @ cam.world_to_camera[:3, :3])
    rgb = np.stack([(world[..., 0] + 1) / 2, (world[..., 1] + 1) / 2,
                    np.full(i.shape, 0.25)], -1).astype(np.float32)
    view = S.View(cam, rgb, np.ones((96, 96), np.float32), np.full((96, 96), 3.0, np.float32))
    return vertices, faces, view


def test_mesh_texture_on_a_known_textured_plane():
    vertices, faces, view = plane_scene()
    size = 64
    baked = T.project_texture(vertices, faces, [view], size, tolerance=0.05)
    assert baked.coverage == 1.0
    assert baked.corner_uvs.shape == (len(faces), 3, 2)
    texels = T.rasterise_uv(vertices, faces, baked.corner_uvs, size)
    got = baked.image.reshape(-1, 3)[texels.texel]
    p = texels.position
    want = np.stack([(p[:, 0] + 1) / 2, (p[:, 1] + 1) / 2, np.full(len(p), 0.25)], 1)
    assert np.abs(got - want).max() < 0.02
    assert np.isfinite(baked.image).all() and baked.image.min() >= 0  # gutters filled


def test_mesh_texture_ignores_occluded_views():
    vertices, faces, view = plane_scene()
    blocked = S.View(view.camera, np.ones_like(view.rgb), view.alpha, np.full_like(view.depth, 1.0))
    baked = T.project_texture(vertices, faces, [blocked, view], 32, tolerance=0.05)
    assert baked.image[..., 2].max() < 0.3  # the white occluder never reaches the plane


def test_fill_texture_fills_every_texel():
    img = np.zeros((16, 16, 3))
    known = np.zeros((16, 16), bool)
    img[3, 4] = [1, 0, 0]
    known[3, 4] = True
    out = T.fill_texture(img, known, dilate=2)
    assert np.allclose(out, [1, 0, 0])
