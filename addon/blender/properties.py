"""The add-on's stored settings: a splat object's render options (`Object.splat`) and its panel,
and the scene's (`Scene.splat_render`, whose panel is in `render/panel.py`).

`obj.splat.is_splat` marks the objects this add-on made (import, or `create_splat_object`);
operators act on those. The options travel with the object (saved in the .blend, copied with
the object, kept by undo):

- `antialiased`: render with the Mip-Splatting opacity compensation (use the mode the splats
  were trained with; an .spz file records it);
- `sh_degree`: the SH bands to evaluate, 0..3 (at most what the data holds);
- `sequence_source`, `sequence_frame_offset`: a splat sequence the object shows frame by frame
  (see `sequence`);
- `color_space`: what the SH colours mean. 'SRGB' (display sRGB, what splats trained on photos
  hold: the reference look) or 'LINEAR' (scene-linear Rec.709). Conversion happens in the render
  integration, not here.

The panel sits in Properties > Object and shows the splat count and the SH degree the data holds.
"""

from __future__ import annotations

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, StringProperty

from .registration import GaussianSplatsPanel, module_registration

COLOR_SPACES = [
    ("SRGB", "sRGB (display)", "Colours are display sRGB, as splats trained on photos are: the "
                               "reference 3DGS look"),
    ("LINEAR", "Linear", "Colours are scene-linear Rec.709"),
]


def _render_owner_switch(settings, context) -> None:
    """A Blender splat point cloud's ray visibility follows who renders it."""
    from .blender_splats import ownership
    ownership.on_setting_changed(settings, context)


def _viewport_switch(settings, context) -> None:
    """The splat object's own display follows whether the add-on draws it (`viewport`)."""
    from . import viewport
    from .blender_splats import ownership
    viewport.on_switch_changed(settings, context)
    if context.scene is not None:
        ownership.sync_scene(context.scene)



# A path that may start with "//" (relative to the .blend, what a render farm needs) is marked
# so where Blender has the flag (5.0 has it, and warns when an unmarked one gets "//"; 4.3 has
# not).
_BLEND_RELATIVE_PATH = ({"PATH_SUPPORTS_BLEND_RELATIVE"}
                        if "is_path_supports_blend_relative" in bpy.types.Property.bl_rna.properties
                        else set())


class SplatObjectSettings(bpy.types.PropertyGroup):
    is_splat: BoolProperty(
        name="Gaussian Splats",
        description="This mesh holds Gaussian splats, one vertex per splat, with their "
                    "parameters as point attributes",
        default=False)
    antialiased: BoolProperty(
        name="Antialiased",
        description="Render with the Mip-Splatting opacity compensation; use the mode the "
                    "splats were trained with",
        default=False)
    sh_degree: IntProperty(
        name="SH Degree",
        description="Spherical-harmonics bands to evaluate (at most what the data holds); "
                    "fewer is faster and less view-dependent",
        default=3, min=0, max=3)
    color_space: EnumProperty(
        name="Colour Space", description="What the splats' colours mean", items=COLOR_SPACES,
        default="SRGB")
    source_path: StringProperty(
        name="Source", description="The file the splats were imported from", subtype="FILE_PATH")
    sequence_source: StringProperty(
        name="Sequence", subtype="FILE_PATH", options=_BLEND_RELATIVE_PATH,
        description="A splat sequence (a numbered file, a #### pattern or a folder): the "
                    "splats are those of the frame's file (empty: not a sequence)")
    sequence_frame_offset: IntProperty(
        name="Frame Offset",
        description="Added to the scene's frame to choose the sequence's file (0: scene frame "
                    "N shows file number N)",
        default=0)
    show_in_viewport: BoolProperty(
        name="Show in Viewport", update=_viewport_switch,
        description="Draw these splats in the 3D viewport (Solid and Material Preview); final "
                    "renders follow the object's render visibility",
        default=True)
    render_by_blender: BoolProperty(
        name="Render with Blender", update=_render_owner_switch,
        description="Blender 5.3 splat point clouds: let Blender's own renderer draw this object "
                    "(Cycles path-traces it with stochastic transparency: lighting, shadows and "
                    "motion blur, but grainy and many times slower, and not the reference 3DGS "
                    "image; EEVEE draws billboards) instead of the add-on's exact composite. Off: "
                    "the add-on composes it exactly and hides it from Blender's rays",
        default=False)


class SplatRenderSettings(bpy.types.PropertyGroup):
    enabled: BoolProperty(
        name="Composite Splats",
        description="Compose the scene's splat objects with the meshes in final renders (F12, "
                    "animation, command-line renders), through the compositor",
        default=True)
    antialiased: EnumProperty(
        name="Antialiased",
        description="Mip-Splatting opacity compensation",
        items=[("OBJECT", "From Objects", "Use the splat objects' own setting (off when they "
                                          "disagree)"),
               ("ON", "On", "Antialiased for every splat object"),
               ("OFF", "Off", "Not antialiased, whatever the objects say")],
        default="OBJECT")
    sh_degree: IntProperty(
        name="Max SH Degree",
        description="Evaluate at most this many spherical-harmonics bands (each object's own "
                    "limit applies too); fewer is faster and less view-dependent",
        default=3, min=0, max=3)
    near: FloatProperty(
        name="Near Plane", description="Splats closer to the camera than this are not drawn",
        default=0.01, min=1e-6, soft_max=1.0, precision=4, subtype="DISTANCE")
    threads: IntProperty(
        name="Threads", description="Threads for the add-on's work on splats: final renders, the "
                                     "viewport, training and mesh conversion (0: as many as "
                                     "Blender renders with: Performance > Threads, or blender "
                                     "-t N). The viewport and training in the background leave "
                                     "Blender's interface a core",
        default=0, min=0, max=1024)
    splat_passes: BoolProperty(
        name="Splat Passes",
        description="Multilayer EXR output also holds the splats' own colour, alpha and depth "
                    "(layer \"Splats\")",
        default=True)
    viewport: BoolProperty(
        name="Show in Viewport", update=_viewport_switch,
        description="Draw splat objects in the 3D viewport (Solid and Material Preview)",
        default=True)
    viewport_coarse_pixels: IntProperty(
        name="Pixels While Moving",
        description="While the view moves, splats are drawn at a resolution of about this many "
                    "pixels; full resolution follows when the view rests",
        default=150_000, min=10_000, max=8_000_000)
    viewport_resolution: FloatProperty(
        name="Viewport Resolution",
        description="Resolution of the resting viewport image, relative to the viewport",
        default=1.0, min=0.1, max=1.0, subtype="FACTOR")
    previous_engine: StringProperty(
        name="Previous Engine", description="The engine \"Render Splats Only\" switched from",
        default="")


class OBJECT_PT_splat(GaussianSplatsPanel, bpy.types.Panel):
    bl_idname = "OBJECT_PT_splat"
    bl_context = "object"

    @classmethod
    def poll(cls, context):
        from .blender_splats import data

        obj = context.object
        return obj is not None and (obj.type == "MESH" and obj.splat.is_splat
                                    or data.is_blender_splat_object(obj))

    def draw(self, context):
        from . import splat_object
        from .sources import live

        obj = context.object
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        if obj.type == "POINTCLOUD":
            self.draw_blender_splats(obj, layout)
            return
        settings = obj.splat
        mesh = obj.data
        degree = splat_object.data_sh_degree(mesh)
        col = layout.column()
        col.label(text=f"{len(mesh.vertices):,} splats, SH degree "
                       f"{'-' if degree is None else degree}")
        snapshot = live.shown(obj)
        if snapshot is not None:  # a running training shows its state in the object's place
            col.label(text=f"Showing step {snapshot[0]:,} of a training: "
                           f"{len(snapshot[1]):,} splats", icon="INFO")
        if degree is None and not mesh.is_editmode:
            col.label(text="Missing splat attributes: " +
                      ", ".join(splat_object.missing_attributes(mesh)), icon="ERROR")
        col.prop(settings, "antialiased")
        col.prop(settings, "sh_degree")
        col.prop(settings, "color_space")
        col.prop(settings, "show_in_viewport")
        if settings.source_path:
            col.prop(settings, "source_path")
        if settings.sequence_source:
            col.prop(settings, "sequence_source")
            col.prop(settings, "sequence_frame_offset")

    @staticmethod
    def draw_blender_splats(obj, layout) -> None:
        """Blender 5.3's own splat point cloud: who renders it, and the add-on's options."""
        from ..core.blender_splats import attributes
        from .blender_splats import data

        settings = obj.splat
        degree, _ = attributes.degree_of(frozenset(data.attribute_names(obj.data)))
        col = layout.column()
        col.label(text=f"Blender splats: {data.point_count(obj.data):,}, SH degree {degree}"
                       + (" (read as 3)" if degree > attributes.RENDER_MAX_DEGREE else ""))
        col.prop(settings, "render_by_blender")
        sub = col.column()
        sub.active = not settings.render_by_blender
        sub.prop(settings, "antialiased")
        sub.prop(settings, "sh_degree")
        sub.prop(settings, "color_space")
        col.operator("splat.convert_from_blender_splats", icon="OUTLINER_OB_POINTCLOUD")


CLASSES = (SplatObjectSettings, SplatRenderSettings, OBJECT_PT_splat)


register, unregister = module_registration(
    CLASSES, pointers=[(bpy.types.Object, "splat", SplatObjectSettings),
                       (bpy.types.Scene, "splat_render", SplatRenderSettings)])
