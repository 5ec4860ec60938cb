"""F12's splat side and the viewport's draw stay short and downhill (scripts/walk.py;
docs/architecture.md, "F12, call by call"): over an add-on splat object and a Blender splat
point cloud, each walk enters the sources' room once, and keeps within issue 34's 20 stays."""

from __future__ import annotations

import bpy_support as bs

from scripts import walk


def _sources_stays(w: walk.Walk) -> int:
    return sum(room == "blender/sources/" for room, *_ in w.stays)


def test_f12_and_the_viewport_draw_walk_downhill():
    try:
        with walk.stand_in():
            camera = walk.build_scene()
            f12 = walk.f12_walks()
            draw = walk.viewport_walks(camera)
    finally:
        bs.reset_scene()
    for name, walks in (("F12", f12), ("viewport draw", draw)):
        for cache, w in walks.items():
            stays, climbs = w.counts()
            assert stays <= 20, (name, cache, w.stays)
            assert _sources_stays(w) == 1, (name, cache, w.stays)
    # the climbs left: core/render and core/colour into core/native.py (docs/architecture.md)
    assert f12["cold"].counts()[1] <= 2 and f12["warm"].counts()[1] <= 2
    assert draw["cold"].counts()[1] <= 1 and draw["warm"].counts()[1] == 0
