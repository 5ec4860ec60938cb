"""The scene's splat render options (`Scene.splat_render`, declared in `properties`) in their
panel in Properties > Render > Gaussian Splats, with the "Render Splats Only" switch and the
compositor bridge's state.

Per-object options (antialiased, SH degree, colour space, shown in the viewport) stay on the
object (`Object.splat`, Properties > Object > Gaussian Splats); the scene options apply to every
splat object of the scene:

- `enabled`: compose the splats into final renders (F12, animation, command line);
- `antialiased`: 'OBJECT' (what the splat objects say), 'ON' or 'OFF' for all;
- `sh_degree`: the most SH bands to evaluate (each object's own limit applies too);
- `near`: the near plane in scene units (splats closer to the camera are culled);
- `threads`: native threads, 0 for as many as Blender renders with (`render.threads`);
- `splat_passes`: add the splat layer to multilayer EXR files;
- `viewport`, `viewport_coarse_pixels`, `viewport_resolution`: the viewport drawing
  (see `viewport`).
"""

from __future__ import annotations

import bpy
from bpy.props import BoolProperty

from . import compositor_bridge as bridge
from ..registration import GaussianSplatsPanel, module_registration


class SPLAT_OT_render_splats_only(bpy.types.Operator):
    """Render only the splats (no mesh render) for quick looks, or switch back to the engine
    used before"""

    bl_idname = "splat.render_splats_only"
    bl_label = "Render Splats Only"
    bl_options = {"REGISTER", "UNDO"}

    enable: BoolProperty(name="Enable", default=True)

    def execute(self, context):
        set_splats_only(context.scene, self.enable)
        return {"FINISHED"}


def set_splats_only(scene, enable: bool) -> None:
    """Switch the scene's render engine to the splats-only engine, or back."""
    settings = scene.splat_render
    if enable and scene.render.engine != bridge.ENGINE_ID:
        settings.previous_engine = scene.render.engine
        scene.render.engine = bridge.ENGINE_ID
    elif not enable and scene.render.engine == bridge.ENGINE_ID:
        scene.render.engine = settings.previous_engine or "CYCLES"


class SPLAT_OT_compositor_bridge(bpy.types.Operator):
    """Set up (or remove) the compositor nodes that bring the splats into final renders"""

    bl_idname = "splat.compositor_bridge"
    bl_label = "Splat Compositor Bridge"
    bl_options = {"REGISTER", "UNDO"}

    remove: BoolProperty(name="Remove", default=False)

    def execute(self, context):
        scene = context.scene
        if self.remove:
            bridge.remove_bridge(scene)
        else:
            bridge.ensure_bridge(scene)
        return {"FINISHED"}


class RENDER_PT_splats(GaussianSplatsPanel, bpy.types.Panel):
    bl_idname = "RENDER_PT_splats"
    bl_context = "render"

    @classmethod
    def poll(cls, context):
        return context.scene is not None and not bridge.is_helper(context.scene)

    def draw(self, context):
        from . import failures, hooks

        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        scene = context.scene
        settings = scene.splat_render
        splats_only = scene.render.engine == bridge.ENGINE_ID
        row = layout.row()
        row.operator(SPLAT_OT_render_splats_only.bl_idname,
                     text="Back to " + (settings.previous_engine or "Cycles").title()
                     if splats_only else "Render Splats Only",
                     icon="LOOP_BACK" if splats_only else "OUTLINER_OB_POINTCLOUD",
                     depress=splats_only).enable = not splats_only
        col = layout.column()
        col.prop(settings, "antialiased")
        col.prop(settings, "sh_degree")
        col.prop(settings, "near")
        col.prop(settings, "threads")
        if not splats_only:
            col = layout.column(heading="Final Render")
            col.prop(settings, "enabled")
            sub = col.column()
            sub.active = settings.enabled
            sub.prop(settings, "splat_passes")
            if settings.enabled:
                found = bridge.problems(scene)
                if found and bridge.bridge_node(scene) is None:
                    box = layout.box()
                    box.label(text="Set up when a scene with splats renders", icon="INFO")
                    box.operator(SPLAT_OT_compositor_bridge.bl_idname, text="Set Up Now").remove = False
                elif found:
                    box = layout.box()
                    for problem in found:
                        box.label(text=problem, icon="ERROR")
                    box.operator(SPLAT_OT_compositor_bridge.bl_idname, text="Repair").remove = False
                else:
                    row = layout.row()
                    row.label(text=f"Composed with view layer \"{bridge.bridge_view_layer(scene)}\"",
                              icon="NODE_COMPOSITING")
                    row.operator(SPLAT_OT_compositor_bridge.bl_idname, text="",
                                 icon="X").remove = True
        col = layout.column(heading="Viewport")
        col.prop(settings, "viewport")
        sub = col.column()
        sub.active = settings.viewport
        sub.prop(settings, "viewport_resolution")
        sub.prop(settings, "viewport_coarse_pixels")
        errors = failures.last_errors()
        if errors:  # the last render failed: say why where the settings are
            box = layout.box()
            box.label(text="The last render failed:", icon="ERROR")
            for line in errors[-1].split("; "):
                box.label(text=line)
        stats = hooks.last_stats
        if stats.get("total_ms"):
            box = layout.box()
            box.label(text=f"Last frame: {int(stats.get('gaussians', 0)):,} splats, "
                           f"{int(stats['width'])}x{int(stats['height'])}, "
                           f"{stats['total_ms']:.0f} ms")


CLASSES = (SPLAT_OT_render_splats_only, SPLAT_OT_compositor_bridge, RENDER_PT_splats)

register, unregister = module_registration(CLASSES)
