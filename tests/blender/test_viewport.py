"""Viewport drawing of splats (bpy + gpu, headless): offscreen, the way the draw handler draws.

Headless Blender has no GPU context until something starts one: a tiny Workbench render does
(through software OpenGL). The viewport's meshes are stood in for by drawing the scene's meshes
into a `GPUOffScreen` with Blender's camera matrices (colour and depth); then the splat image
is drawn over them with `viewport.draw_image`, exactly as the POST_VIEW handler does.
"""

from __future__ import annotations

import math

import bpy_support as bs
from bpy_support import bpy  # the shared bpy import
import numpy as np
import pytest

from addon.blender import splat_object, viewport
from addon.core.render.renderer import RenderResult, viewport_image
from scenes import random_gaussians

W, H = 48, 36


@pytest.fixture(scope="module", autouse=True)
def gpu_context():
    bs.reset_scene()
    scene = bpy.context.scene
    bs.add_camera(width=8, height=8)
    scene.render.engine = "BLENDER_WORKBENCH"
    bpy.ops.render.render()  # brings up the (software) GPU context
    yield


def view_matrices(camera_obj):
    depsgraph = bpy.context.evaluated_depsgraph_get()
    view = np.array(camera_obj.matrix_world.inverted())
    window = np.array(camera_obj.calc_matrix_camera(depsgraph, x=W, y=H))
    return view, window


def draw_meshes(objects, view, window, colour):
    """The viewport's part: meshes drawn with a depth test into the bound framebuffer."""
    import gpu
    import mathutils
    from gpu_extras.batch import batch_for_shader

    shader = gpu.shader.from_builtin("UNIFORM_COLOR")
    gpu.state.depth_test_set("LESS_EQUAL")
    gpu.state.depth_mask_set(True)
    with gpu.matrix.push_pop(), gpu.matrix.push_pop_projection():
        gpu.matrix.load_matrix(mathutils.Matrix(view.tolist()))
        gpu.matrix.load_projection_matrix(mathutils.Matrix(window.tolist()))
        for obj in objects:
            mesh = obj.data
            mesh.calc_loop_triangles()
            world = np.array(obj.matrix_world)
            co = np.array([world[:3, :3] @ v.co + world[:3, 3] for v in mesh.vertices])
            tris = [co[list(t.vertices)] for t in mesh.loop_triangles]
            batch = batch_for_shader(shader, "TRIS", {"pos": np.concatenate(tris).tolist()})
            shader.uniform_float("color", colour)
            batch.draw(shader)
    gpu.state.depth_mask_set(False)
    gpu.state.depth_test_set("NONE")


def offscreen_draw(meshes, view, window, image=None):
    import gpu

    offscreen = gpu.types.GPUOffScreen(W, H, format="RGBA8")
    with offscreen.bind():
        framebuffer = gpu.state.active_framebuffer_get()
        framebuffer.clear(color=(0.0, 0.0, 0.0, 0.0), depth=1.0)
        draw_meshes(meshes, view, window, (0.0, 1.0, 0.0, 1.0))
        if image is not None:
            viewport.draw_image(image)
        pixels = np.array(framebuffer.read_color(0, 0, W, H, 4, 0, "UBYTE").to_list(), np.int32)
    offscreen.free()
    return pixels[::-1]  # rows top to bottom


def test_camera_from_view_is_blenders_camera(rng):
    camera = bs.add_camera(location=(0.3, -5.0, 0.4), rotation=(1.4, 0.1, 0.2), lens=28,
                           width=W, height=H)
    camera.data.shift_x = 0.05
    view, window = view_matrices(camera)
    ours = viewport.camera_from_view(view, window, W, H)
    blender = bs.camera_of(camera, bpy.context.evaluated_depsgraph_get())
    for name in ("fx", "fy", "cx", "cy"):
        assert getattr(ours, name) == pytest.approx(getattr(blender, name), rel=1e-5)
    assert np.allclose(ours.world_to_camera, blender.world_to_camera, atol=1e-5)
    odd = window.copy()
    odd[3] = (0, 0, 0.5, 0.5)  # neither perspective nor orthographic
    assert viewport.camera_from_view(view, odd, W, H) is None
    half = viewport.camera_from_view(view, window, W, H, scale=0.5)
    assert (half.width, half.height) == (W // 2, H // 2)
    assert half.fx == pytest.approx(ours.fx / 2)


def test_orthographic_view_is_blenders_orthographic_camera(rng):
    camera = bs.add_camera(location=(0.3, -5.0, 0.4), rotation=(1.4, 0.1, 0.2), lens=28,
                           width=W, height=H)
    camera.data.type = "ORTHO"
    camera.data.ortho_scale = 3.7
    camera.data.shift_x, camera.data.shift_y = 0.05, -0.1
    view, window = view_matrices(camera)
    ours = viewport.camera_from_view(view, window, W, H)
    blender = bs.camera_of(camera, bpy.context.evaluated_depsgraph_get())
    assert ours.model == blender.model == "ORTHO"
    for name in ("fx", "fy", "cx", "cy"):
        assert getattr(ours, name) == pytest.approx(getattr(blender, name), rel=1e-5)
    assert np.allclose(ours.world_to_camera, blender.world_to_camera, atol=1e-5)
    assert ours.far == pytest.approx(camera.data.clip_end, rel=1e-5)
    # (from float32 matrix entries: (P23 + 1) / P22 cancels to about 1e-7 clip_end)
    assert viewport.view_near(window, 0.01) == pytest.approx(camera.data.clip_start, abs=1e-3)
    # An orthographic viewport clips from -clip_end/2 (behind its origin) to clip_end/2.
    viewport_window = window.copy()
    viewport_window[2, 2], viewport_window[2, 3] = -2 / 100.0, 0.0  # clip -50..50
    assert viewport.view_near(viewport_window, 0.01) == pytest.approx(-50.0)
    depth = np.float32([[-20.0, 0.0, 25.0, np.inf]])
    flat = RenderResult(np.zeros((1, 4, 3), np.float32), np.zeros((1, 4), np.float32), depth)
    stored = viewport_image(flat, viewport_window)[1]
    np.testing.assert_allclose(stored, [[0.3, 0.5, 0.75, 1.0]], atol=1e-6)


@pytest.mark.parametrize("kind", ["PERSP", "ORTHO"])
def test_drawn_splats_are_occluded_by_a_mesh_in_front(rng, kind):
    bs.reset_scene()
    g = random_gaussians(rng, 500, 1, radius=1.0, stray=0.0)
    g.opacity_logits[:] = np.abs(g.opacity_logits) + 2.0  # mostly opaque: a clear test
    splat_object.create_splat_object(g, "Splats")
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0.4, -2.5, 0.0))
    cube = bpy.context.active_object
    bpy.ops.mesh.primitive_plane_add(size=40, location=(0, 3.0, 0), rotation=(math.pi / 2, 0, 0))
    plane = bpy.context.active_object
    camera = bs.add_camera(location=(0, -6, 0), rotation=(math.pi / 2, 0, 0), lens=35,
                           width=W, height=H)
    camera.data.type = kind
    camera.data.ortho_scale = 3.0
    view, window = view_matrices(camera)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    gaussians, options = viewport.viewport_splats(depsgraph, bpy.context.scene)
    image = viewport.render_view(gaussians, viewport.camera_from_view(view, window, W, H),
                                 window, **options)
    if kind == "ORTHO":  # the native orthographic render of the same view, pixel for pixel
        from addon.core.render.renderer import render
        alone = render(gaussians, bs.camera_of(camera, depsgraph), near=camera.data.clip_start)
        assert np.abs(image.rgba[::-1, :, 3] - alone.alpha).max() < 1e-6

    cube_only = offscreen_draw([cube], view, window)
    meshes = offscreen_draw([cube, plane], view, window)
    drawn = offscreen_draw([cube, plane], view, window, image)
    on_cube = cube_only[..., 3] == 255
    splat_rgba = np.round(np.clip(image.rgba[::-1], 0, 1) * 255)
    opaque = image.rgba[::-1, :, 3] > 0.97
    assert on_cube.sum() > 20 and (opaque & on_cube).sum() > 5
    # The cube hides the splats behind it...
    assert np.array_equal(drawn[on_cube], meshes[on_cube])
    # ...and the splats hide the plane behind them (premultiplied "over").
    behind = opaque & ~on_cube
    assert behind.sum() > 20
    expected = splat_rgba[behind][:, :3] + (1 - image.rgba[::-1][behind][:, 3:]) * meshes[behind][:, :3]
    expected = np.minimum(expected, 255)  # the framebuffer saturates (a bright splat over a bright plane)
    assert np.abs(drawn[behind][:, :3] - expected).max() <= 2
    # Where nothing is drawn, the framebuffer is untouched.
    empty = image.rgba[::-1, :, 3] < 1 / 255
    assert np.array_equal(drawn[empty], meshes[empty])


def test_background_renderer_and_switches(rng):
    bs.reset_scene()
    a = splat_object.create_splat_object(random_gaussians(rng, 200, 1), "A")
    b = splat_object.create_splat_object(random_gaussians(rng, 100, 0), "B")
    scene = bpy.context.scene
    gaussians, _ = viewport.viewport_splats(bpy.context.evaluated_depsgraph_get(), scene)
    assert len(gaussians) == 300
    b.splat.show_in_viewport = False
    gaussians, options = viewport.viewport_splats(bpy.context.evaluated_depsgraph_get(), scene)
    assert len(gaussians) == 200
    a.splat.show_in_viewport = False
    assert viewport.viewport_splats(bpy.context.evaluated_depsgraph_get(), scene) is None

    camera = bs.add_camera(width=W, height=H)
    view, window = view_matrices(camera)
    cam = viewport.camera_from_view(view, window, W, H)
    worker = viewport.ViewportRenderer()
    try:
        worker.submit(viewport._Job(1, ("coarse",), gaussians, viewport.camera_from_view(
            view, window, W, H, 0.25), window, True, options))
        worker.submit(viewport._Job(2, ("full",), gaussians, cam, window, False, options))
        assert worker.wait(30)
        assert worker.take_fresh() and not worker.take_fresh()
        direct = viewport.render_view(gaussians, cam, window, **options)
        assert np.array_equal(worker.result(2).rgba, direct.rgba)
        assert worker.result(1).rgba.shape[:2] == (round(H * 0.25), round(W * 0.25))
    finally:
        worker.stop()


def _view_context(scene, view, window, width: int, height: int, region_id: int):
    """A stand-in for a 3D view's draw-callback context (what `viewport.draw_view` reads)."""
    import mathutils

    region = type("Region", (), dict(width=width, height=height,
                                     as_pointer=lambda self: region_id))()
    return type("Context", (), dict(
        scene=scene, region=region,
        space_data=type("Space", (), dict(type="VIEW_3D", shading=type("S", (), dict(type="SOLID"))()))(),
        region_data=type("RV3D", (), dict(view_matrix=mathutils.Matrix(view.tolist()),
                                          window_matrix=mathutils.Matrix(window.tolist())))(),
        evaluated_depsgraph_get=staticmethod(bpy.context.evaluated_depsgraph_get)))()


def _splats_in_view(rng, width: int, height: int, count: int = 200):
    """A scene with a splat object of `count` random splats and a camera; (scene, the object,
    the camera's view matrix, its window matrix for a width x height view)."""
    bs.reset_scene()
    obj = splat_object.create_splat_object(random_gaussians(rng, count, 1, radius=1.0), "Splats")
    camera = bs.add_camera(width=W, height=H)
    view, _ = view_matrices(camera)
    window = np.array(camera.calc_matrix_camera(bpy.context.evaluated_depsgraph_get(),
                                                x=width, y=height))
    return bpy.context.scene, obj, view, window


def test_draw_handler_is_progressive(rng):
    """The handler's logic with a stand-in for the 3D view's context: a coarse image first,
    full resolution once the view rests, drawn offscreen."""
    import gpu

    width, height = 160, 120
    scene, _, view, window = _splats_in_view(rng, width, height, 300)
    scene.splat_render.viewport_coarse_pixels = 10_000

    context = _view_context(scene, view, window, width, height, 4242)
    offscreen = gpu.types.GPUOffScreen(width, height, format="RGBA8")
    try:
        with offscreen.bind():
            viewport.draw_view(context)           # the view is new: a coarse render starts
            assert viewport.renderer.wait(30)
            coarse = viewport.renderer.result(4242)
            assert coarse.coarse and coarse.rgba.shape[0] < height
            viewport._views[4242].changed_at -= 1.0   # the view has rested
            viewport._tick()                       # the timer asks for full resolution
            assert viewport.renderer.wait(30)
            full = viewport.renderer.result(4242)
            assert not full.coarse and full.rgba.shape[:2] == (height, width)
            framebuffer = gpu.state.active_framebuffer_get()
            framebuffer.clear(color=(0.0, 0.0, 0.0, 0.0), depth=1.0)
            viewport.draw_view(context)           # same view: draws the full image, no new job
            assert not viewport.renderer.busy()
            pixels = np.array(framebuffer.read_color(0, 0, width, height, 4, 0, "UBYTE").to_list())
        expected = np.round(np.clip(full.rgba, 0, 1) * 255)
        assert np.abs(pixels - expected)[full.rgba[..., 3] > 1 / 255].max() <= 2
        # The splats change, the view does not (training's updates): straight to full
        # resolution, the last image drawn meanwhile, no coarse one between.
        splat_object.replace_gaussians(bpy.data.objects["Splats"],
                                       random_gaussians(rng, 300, 1, radius=1.0))
        with offscreen.bind():
            viewport.draw_view(context)
            assert viewport.renderer.wait(30)
        update = viewport.renderer.result(4242)
        assert not update.coarse and update.rgba.shape[:2] == (height, width)
        assert not np.array_equal(update.rgba, full.rgba)
        scene.splat_render.viewport = False       # the scene switch: nothing drawn
        viewport.draw_view(context)
    finally:
        offscreen.free()
        viewport.renderer.forget(4242)
        viewport._views.clear()
        viewport._texture_cache.clear()


def test_a_jobs_snapshot_renders_before_any_redraw(rng, monkeypatch):
    """Training's update (a snapshot shown in place of the object's data): `refresh` asks for
    the view's new image at once, so the view redraws once, when it is ready, which draws it
    without a new job; not a redraw to see the new splats and one more for their image."""
    from addon.blender.sources import live

    width, height = 80, 60
    scene, obj, view, window = _splats_in_view(rng, width, height)
    context = _view_context(scene, view, window, width, height, 4444)
    drawn = []
    monkeypatch.setattr(viewport, "draw_image", lambda image, cache_key=None: drawn.append(image))
    try:
        viewport.refresh()                     # headless: no windows, nothing to refresh
        assert not viewport.renderer.busy()
        viewport.draw_view(context)
        assert viewport.renderer.wait(30)
        viewport._views[4444].changed_at -= 1.0
        viewport._tick()
        assert viewport.renderer.wait(30)
        before = viewport.renderer.result(4444)
        live.show(obj, random_gaussians(rng, 200, 1, radius=1.0), 100)
        monkeypatch.setattr(viewport, "_views_on_screen", lambda: iter([(
            scene, bpy.context.evaluated_depsgraph_get(), context.region, context.region_data)]))
        viewport.refresh()
        assert viewport.renderer.wait(30)
        after = viewport.renderer.result(4444)
        assert after.key != before.key and not after.coarse
        assert not np.array_equal(after.rgba, before.rgba)
        submitted = []
        monkeypatch.setattr(viewport.renderer, "submit", submitted.append)
        viewport.draw_view(context)            # the one redraw: the new image, no new job
        assert drawn[-1] is after and submitted == []
    finally:
        live.end(obj)
        viewport.renderer.forget(4444)
        viewport._views.clear()
        viewport._texture_cache.clear()


def test_a_rested_view_never_shows_another_views_image(rng, monkeypatch):
    """After a view change (numpad 1/3/7, numpad 5, the end of an orbit) the image of the view
    before is drawn only while the view moves; once it rests, only this view's image, or
    nothing until it is ready."""

    width, height = 80, 60
    scene, _, view, window = _splats_in_view(rng, width, height)

    def context_for(view_matrix):
        return _view_context(scene, view_matrix, window, width, height, 4343)

    drawn = []
    monkeypatch.setattr(viewport, "draw_image", lambda image, cache_key=None: drawn.append(image.key))
    turned = view.copy()
    turned[:3, :3] = view[:3, :3] @ np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])  # 90 degrees
    try:
        viewport.draw_view(context_for(view))
        assert viewport.renderer.wait(30)
        before = viewport.renderer.result(4343).key
        held = []   # the new view's jobs, held back: its image is not ready
        monkeypatch.setattr(viewport.renderer, "submit", held.append)
        viewport.draw_view(context_for(turned))       # moving: the last image may stay up
        assert drawn[-1] == before and held
        viewport._views[4343].view_changed_at -= 1.0  # the view has rested
        drawn.clear()
        viewport.draw_view(context_for(turned))
        assert drawn == []                            # not the view before: nothing
        monkeypatch.undo()
        monkeypatch.setattr(viewport, "draw_image", lambda image, cache_key=None: drawn.append(image.key))
        for job in held:
            viewport.renderer.submit(job)
        assert viewport.renderer.wait(30)
        viewport.draw_view(context_for(turned))
        assert drawn and viewport.view_of(drawn[-1]) == viewport.view_of(viewport._views[4343].key)
    finally:
        viewport.renderer.forget(4343)
        viewport._views.clear()
        viewport._texture_cache.clear()


def test_a_late_image_of_the_view_before_never_replaces_this_views():
    """The full image of the view before, finished after this view's coarse one, is not kept."""
    worker = viewport.ViewportRenderer()
    image = lambda key, coarse: viewport.ViewportImage(key, np.zeros((1, 1, 4), np.float32),  # noqa: E731
                                                       np.ones((1, 1), np.float32), coarse, 0.0)
    now, before = ("v", "w", 8, 6, "splats"), ("u", "w", 8, 6, "splats")
    worker._wanted[1] = viewport.view_of(now)
    worker._results[1] = image(now, True)
    assert not worker._keeps(1, image(before, False))      # late, of the view before
    assert worker._keeps(1, image(now, False))             # this view's full image
    worker._results[1] = image(now, False)
    assert not worker._keeps(1, image(now, True))          # coarse never replaces full
    worker._results[1] = image(before, False)
    assert worker._keeps(1, image(now, True))              # this view's coarse beats it


def test_splat_objects_show_their_bounds_not_their_vertices(rng):
    """Blender would draw one dot per splat over the add-on's image: a splat object the add-on
    draws is displayed as its bounds; with its drawing off it shows its points again; a display
    the user picked is left alone."""
    bs.reset_scene()
    scene = bpy.context.scene
    obj = splat_object.create_splat_object(random_gaussians(rng, 50, 0), "Splats")
    viewport._on_load_post()  # what opening a file does (new objects: the depsgraph handler)
    assert obj.display_type == "BOUNDS"
    obj.splat.show_in_viewport = False
    assert obj.display_type == "TEXTURED"
    obj.splat.show_in_viewport = True
    assert obj.display_type == "BOUNDS"
    scene.splat_render.viewport = False
    assert obj.display_type == "TEXTURED"
    scene.splat_render.viewport = True
    obj.display_type = "WIRE"  # the user's choice
    viewport.sync_scene(scene)
    assert obj.display_type == "WIRE"
    plain = bpy.data.objects.new("Plain", bpy.data.meshes.new("Plain"))
    scene.collection.objects.link(plain)
    viewport.sync_scene(scene)
    assert plain.display_type == "TEXTURED"  # not a splat object
