"""The training panel: 3D View > Sidebar > Gaussian Splats > Training.

It starts Train Gaussians and Bake to Splats, and while either runs in the background shows
its progress from the job runner (`job_runner.RUNNING`): the step, the Gaussian count as the
strategy sizes it ("growing" while added Gaussians still lower the training loss, then
"settled"), the training-view PSNR, for a run until done the held-out gain per minute that
decides when it stops, and a stop button. The job runner's timer redraws the 3D View, so the
numbers follow the run.
"""

from __future__ import annotations

import bpy

from ...core.jobs import Progress, format_duration, how_far
from .. import job_runner
from ..registration import module_registration


def _draw_job(layout, running: job_runner.OperatorJob) -> None:
    p: Progress = running.progress
    box = layout.box()
    name = running.key.split(":", 1)[-1]
    header = box.row(align=True)
    header.label(text=f"{running.title}: {name}", icon="SHADERFX")
    stop = header.operator(job_runner.SPLAT_OT_train_stop.bl_idname, text="", icon="CANCEL")
    stop.key = running.key
    col = box.column(align=True)
    if p.phase not in ("training", "done", "cancelled"):
        col.progress(factor=p.fraction, type="BAR", text=p.message or p.phase)
        return
    if p.until_done:
        col.label(text=how_far(p).capitalize())
    else:
        col.progress(factor=p.fraction, type="BAR", text=how_far(p).capitalize())
    col.label(text=f"{p.gaussians:,} Gaussians" + (f", {p.sizing}" if p.sizing else ""),
              icon="POINTCLOUD_DATA")
    if p.psnr == p.psnr:
        col.label(text=f"Training PSNR {p.psnr:.2f} dB")
    if p.until_done:
        gain = (f"{p.gain_per_minute:+.2f} dB/min" if p.gain_per_minute == p.gain_per_minute
                else "measuring")
        col.label(text=f"Held-out gain {gain}")
    elif p.eta is not None:
        col.label(text=f"ETA {format_duration(p.eta)}")


class VIEW3D_PT_splat_training(bpy.types.Panel):
    bl_label = "Training"
    bl_idname = "VIEW3D_PT_splat_training"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Gaussian Splats"

    def draw(self, context):
        layout = self.layout
        row = layout.row(align=True)
        row.operator("splat.train", text="Train", icon="SHADERFX")
        row.operator("splat.bake_to_splats", text="Bake", icon="RENDER_STILL")
        for running in list(job_runner.RUNNING.values()):
            _draw_job(layout, running)


CLASSES = (VIEW3D_PT_splat_training,)
register, unregister = module_registration(CLASSES)
