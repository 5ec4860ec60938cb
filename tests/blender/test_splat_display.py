"""A splat object's display (bounds, not one dot per splat) after everything that brings objects
back from stored state: undo, redo, file load, append, link, duplicate (bpy, headless).

The UI half (the screenshots after Ctrl+Z in real Blender) is tests/real_blender/undo_display.py.
"""

from __future__ import annotations

import bpy_support as bs
from bpy_support import bpy  # the shared bpy import
import pytest

from addon.blender import splat_object, viewport
from addon.core.formats import registry
from scenes import random_gaussians


def _splats(scene=None):
    return [o for o in (scene or bpy.context.scene).objects if splat_object.is_splat_object(o)]


def _push(message: str) -> None:
    bpy.ops.ed.undo_push(message=message)


@pytest.fixture
def ply(tmp_path, rng):
    path = tmp_path / "splats.ply"
    g = random_gaussians(rng, 300, 1)
    g.opacity_logits[:60] = -9.0  # transparent: Clean Up removes them
    registry.write(g, path)
    return path


def test_created_objects_are_bounds_at_once(rng):
    """The display is set where the object is made (inside the operator, so its undo step holds
    it), not later by a handler or timer."""
    bs.reset_scene()
    handlers = bpy.app.handlers.depsgraph_update_post[:]
    bpy.app.handlers.depsgraph_update_post.clear()  # no handler may be what sets it
    try:
        obj = splat_object.create_splat_object(random_gaussians(rng, 20, 0), "Splats")
    finally:
        bpy.app.handlers.depsgraph_update_post.extend(handlers)
    assert obj.display_type == "BOUNDS" and obj.get(viewport.BOUNDS_FLAG)


def test_undo_and_redo_of_import_and_clean_up_keep_bounds(ply):
    """The issue's path: import, Clean Up, undo, redo, Edit Mode delete, undo twice."""
    bs.reset_scene()
    _push("empty")
    assert bpy.ops.splat.import_splats(filepath=str(ply)) == {"FINISHED"}
    _push("import")
    (obj,) = _splats()
    assert obj.display_type == "BOUNDS"
    assert bpy.ops.splat.clean_up() == {"FINISHED"}
    _push("clean up")
    assert len(_splats()[0].data.vertices) < 300
    for step, (operator, count) in enumerate([(bpy.ops.ed.undo, 300), (bpy.ops.ed.redo, None)]):
        operator()
        (obj,) = _splats()
        assert obj.display_type == "BOUNDS", step
        if count is not None:
            assert len(obj.data.vertices) == count
    bpy.context.view_layer.objects.active = obj
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.select_all(action="SELECT")
    bpy.ops.mesh.delete(type="VERT")
    _push("delete")
    bpy.ops.ed.undo()
    bpy.ops.ed.undo()
    (obj,) = _splats()
    assert obj.display_type == "BOUNDS"


def test_undo_to_a_state_stored_without_bounds_is_fixed(rng):
    """A step stored before the add-on set the display (older files, or the timer of earlier
    versions): undo and redo put it right at once (undo_post, redo_post)."""
    bs.reset_scene()
    obj = splat_object.create_splat_object(random_gaussians(rng, 20, 0), "Splats")
    _as_stored_without_bounds(obj)
    obj.location.x = 0.0
    _push("old")
    bpy.data.objects["Splats"].location.x = 1.0
    _push("moved")
    bpy.ops.ed.undo()
    obj = bpy.data.objects["Splats"]
    assert obj.location.x == 0.0 and obj.display_type == "BOUNDS"
    _as_stored_without_bounds(obj)
    viewport._on_stored_state()  # what redo_post runs
    assert obj.display_type == "BOUNDS"
    assert viewport._on_stored_state in bpy.app.handlers.redo_post
    assert viewport._on_stored_state in bpy.app.handlers.undo_post


def _as_stored_without_bounds(obj) -> None:
    """The object as an older version stored it before its timer set Bounds: Textured, and
    not flagged as given Bounds by the add-on."""
    obj.display_type = "TEXTURED"
    del obj[viewport.BOUNDS_FLAG]


def _save_textured(tmp_path, rng, name: str = "stored.blend"):
    """A .blend whose splat object is stored with Blender's own display (dots)."""
    bs.reset_scene()
    obj = splat_object.create_splat_object(random_gaussians(rng, 20, 0), "Stored")
    _as_stored_without_bounds(obj)
    path = tmp_path / name
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return path


def test_file_load_append_and_duplicate_show_bounds(tmp_path, rng):
    path = _save_textured(tmp_path, rng)
    bpy.ops.wm.open_mainfile(filepath=str(path))
    bs.ensure_registered()
    assert bpy.data.objects["Stored"].display_type == "BOUNDS"

    bs.reset_scene()
    bpy.ops.wm.append(directory=str(path) + "/Object/", filename="Stored")
    bpy.context.view_layer.update()  # what the UI's redraw does (depsgraph_update_post)
    assert bpy.data.objects["Stored"].display_type == "BOUNDS"

    obj = bpy.data.objects["Stored"]
    _as_stored_without_bounds(obj)  # the duplicate copies what the original has
    for other in bpy.context.view_layer.objects:
        other.select_set(other == obj)
    bpy.context.view_layer.objects.active = obj
    bpy.ops.object.duplicate()
    bpy.context.view_layer.update()
    assert len(_splats()) == 2
    assert all(o.display_type == "BOUNDS" for o in _splats())


def test_linked_objects_are_left_alone(tmp_path, rng):
    """Library data cannot be written: the handlers must not raise for it."""
    path = _save_textured(tmp_path, rng, "library.blend")
    bs.reset_scene()
    bpy.ops.wm.link(directory=str(path) + "/Object/", filename="Stored")
    bpy.context.view_layer.update()
    linked = bpy.data.objects["Stored"]
    assert linked.library is not None
    assert viewport.sync_all() == 0 and not viewport.needs_sync(linked, bpy.context.scene)


def test_a_user_display_choice_survives_undo(rng):
    bs.reset_scene()
    obj = splat_object.create_splat_object(random_gaussians(rng, 20, 0), "Splats")
    obj.display_type = "WIRE"
    _push("wire")
    bpy.data.objects["Splats"].location.x = 2.0
    _push("moved")
    bpy.ops.ed.undo()
    assert bpy.data.objects["Splats"].display_type == "WIRE"


def test_textured_picked_by_the_user_is_kept(rng):
    """Display As Textured on an object the add-on gave Bounds is the user's choice: neither
    the depsgraph handler nor undo or load turn it back (new objects still get Bounds)."""
    bs.reset_scene()
    obj = splat_object.create_splat_object(random_gaussians(rng, 20, 0), "Splats")
    obj.display_type = "TEXTURED"
    bpy.context.view_layer.update()
    assert obj.display_type == "TEXTURED"
    viewport._on_stored_state()
    assert obj.display_type == "TEXTURED"
    obj.splat.show_in_viewport = False  # the add-on's drawing off, then on: still the user's
    obj.splat.show_in_viewport = True
    assert obj.display_type == "TEXTURED"
