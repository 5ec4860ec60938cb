"""Runs inside a real Blender before it renders a saved splat scene: takes away what a user or
a script takes away, so that the farm test (scripts/test_farm.py) can check that the render
neither crashes nor loses the splats silently.

    blender -b [--factory-startup] -y SCENE.blend -o OUT --python damage.py -f 1 -- CASE

CASE: nothing; compositing-off (Post Processing > Compositing); hide-render / hide-viewport /
delete (the splat object); empty-objects (a generation script's
`for o in bpy.data.objects: bpy.data.objects.remove(o)`, then the scene is built again from
copies); helper-renamed / helper-deleted (the helper scene); node-deleted / node-renamed (the
Splat Composite node); camera-cleared (the helper scene's borrowed camera). Plain bpy: it
also runs with --factory-startup, where the add-on is absent.
"""

import sys

import bpy

HELPER_FLAG = "splat_composite_helper"   # compositor_bridge.HELPER_FLAG
BRIDGE_FLAG = "splat_bridge"             # compositor_bridge.BRIDGE_FLAG


def helper():
    return next(s for s in bpy.data.scenes if s.get(HELPER_FLAG))


def bridge_node(scene):
    tree = scene.compositing_node_group
    return next(n for n in tree.nodes if n.get(BRIDGE_FLAG) is not None)


def empty_objects(scene):
    camera = scene.camera
    matrix = camera.matrix_world.copy()
    animation = camera.animation_data.action if camera.animation_data else None
    originals = list(bpy.data.objects)
    copies = {o.name: o.copy() for o in scene.objects}
    for obj in originals:
        bpy.data.objects.remove(obj)
    for name, obj in copies.items():
        obj.name = name
        scene.collection.objects.link(obj)
        if obj.type == "CAMERA":
            scene.camera = obj
            obj.matrix_world = matrix
            if animation is not None:
                obj.animation_data_create().action = animation


def main(case: str) -> None:
    scene = bpy.data.scenes["Scene"]
    splats = bpy.data.objects.get("Splats")
    if case == "nothing":
        pass
    elif case == "compositing-off":
        scene.render.use_compositing = False
    elif case == "hide-render":
        splats.hide_render = True
    elif case == "hide-viewport":
        splats.hide_viewport = True
    elif case == "delete":
        bpy.data.objects.remove(splats)
    elif case == "empty-objects":
        empty_objects(scene)
    elif case == "helper-renamed":
        helper().name = "Renamed by a script"
    elif case == "helper-deleted":
        bpy.data.scenes.remove(helper())
    elif case == "node-deleted":
        scene.compositing_node_group.nodes.remove(bridge_node(scene))
    elif case == "node-renamed":
        node = bridge_node(scene)
        node.name = node.label = "Something else"
    elif case == "camera-cleared":
        helper().camera = None
    else:
        raise SystemExit(f"unknown case {case!r}")
    print(f"damage: {case} done", flush=True)


main(sys.argv[sys.argv.index("--") + 1])
