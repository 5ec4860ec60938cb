"""Photos or a video to a scene: File > Import > Photos or Video (reconstruct cameras).

    bpy.ops.splat.import_photos(filepath="/path/to/photos/", output="/path/to/scene")

Finds the cameras with `core.sfm` in a process of its own (`core.sfm.process`: Blender stays
responsive, Esc ends it at once, and a run again resumes from the stages it cached in the output
folder), then imports the workspace exactly as File > Import > COLMAP Scene does (`colmap_import`:
cameras with photo backgrounds, points, upright, Standard look, a light for meshes) and, with
Train After, starts training on it. Cancelled or failed at any stage, the scene is left as it was.
The report says how many photos were placed of how many and names those left out, with why.
"""

from __future__ import annotations

from pathlib import Path

import bpy
from bpy.props import BoolProperty, EnumProperty, IntProperty, StringProperty

from ...core.jobs import StagedJob, ui_kernel_threads
from ...core.sfm.pipeline import Options
from ...core.sfm.process import ReconstructionProcess
from ...core.sfm.source import VIDEO_SUFFIXES
from .. import dependencies
from ..job_runner import JobOperator, OperatorJob, draw_settings, wants_background
from ..registration import module_registration
from . import colmap_import

DEFAULTS = Options()  # the operator's defaults are the verb's and the pipeline's

# What Import COLMAP needs (pycolmap in this process or, in a distribution's Blender, in a child
# process: `dependencies`); PyAV, for videos, is the reconstruction's child process's to load.
MODULES = colmap_import.MODULES
FEATURE = "Reconstructing cameras from photos"
STAGES = ("reconstructing", "importing")
WEIGHTS = (0.95, 0.05)  # of the progress bar: the import is a few seconds


def default_output(source: Path) -> Path:
    """`<folder>_scene` beside a folder of photos, `<video name>_scene` beside a video."""
    source = source.resolve()
    return source.parent / f"{source.stem if source.is_file() else source.name}_scene"


def reconstruct_steps(source: Path, output: Path, options: dict, import_options: dict):
    """Generator of (stage, fraction, status) for `StagedJob`: the child process (yielding None
    while it works, so that Blender's main thread only looks in on it), then the import;
    returns (report as JSON, the new collection). Closing it ends the child."""
    process = ReconstructionProcess(source, output, options)
    try:
        while process.running:
            step = process.step
            if step is None:
                yield "reconstructing", 0.0, "starting"
            else:
                yield "reconstructing", step["fraction"], step["line"]
            yield None
        report = process.report()
    finally:
        process.stop()
    steps = colmap_import.import_steps(output, "images", **import_options)
    try:  # closing this generator closes the import, which removes what it built
        while True:
            try:
                step = next(steps)
            except StopIteration as done:
                collection = done.value
                break
            if step is None:  # the reader works on its own thread
                yield None
                continue
            stage, fraction = step
            parts = len(colmap_import.STAGES)
            yield ("importing", (colmap_import.STAGES.index(stage) + fraction) / parts,
                   "importing the scene")
    finally:
        steps.close()
    collection["reconstruction_left_out"] = "\n".join(f"{n}: {w}" for n, w in report["left_out"])
    return report, collection


def report_message(report: dict) -> tuple[str, str]:
    """(level, message) for the user: placed of how many, and the ones left out, named."""
    what = "frames" if report["kind"] == "video" else "photos"
    message = (f"placed {len(report['registered'])} of {report['photos']} {what} "
               f"({report['mapper']} mapping, {report['matching']} matching)")
    left = report["left_out"] + report["skipped"]
    if not left:
        return "INFO", message
    shown = "; ".join(f"{name}: {why}" for name, why in left[:4])
    more = f"; and {len(left) - 4} more (listed in {report['workspace']}/reconstruction.json)" \
        if len(left) > 4 else ""
    return "WARNING", f"{message}; left out {shown}{more}"


class SPLAT_OT_import_photos(JobOperator, bpy.types.Operator):
    """Find the cameras of a folder of photos or a video (structure from motion, on the CPU)
    and import them as a COLMAP scene: cameras with the photos, points, ready to train"""

    bl_idname = "splat.import_photos"
    bl_label = "Import Photos or Video"
    bl_options = {"REGISTER", "UNDO"}

    filepath: StringProperty(name="Photos or Video", subtype="FILE_PATH",
                             description="A folder of photos (open it and accept) or a video "
                                         "file")
    filter_folder: BoolProperty(default=True, options={"HIDDEN"})
    filter_image: BoolProperty(default=True, options={"HIDDEN"})
    filter_movie: BoolProperty(default=True, options={"HIDDEN"})
    output: StringProperty(name="Output Folder", subtype="DIR_PATH", default="",
                           description="Where the COLMAP workspace goes (photos, database, "
                                       "model); empty: '<name>_scene' beside the photos or "
                                       "video. Running again on it resumes")
    frames: IntProperty(name="Video Frames", default=DEFAULTS.frames, min=3, soft_max=1000,
                        description="Frames taken from a video: the sharpest of each equal "
                                    "slice of time")
    max_size: IntProperty(name="Max Size", default=DEFAULTS.max_size, min=0, soft_max=8192,
                          subtype="PIXEL", description="Long side of the photos kept for "
                                                       "training (0: as they are)")
    features: EnumProperty(name="Features", default=DEFAULTS.features, items=[
        ("accurate", "Accurate", "SIFT with affine shapes and domain-size pooling: the more "
                                 "exact cameras (on the demo, half the largest rotation error)"),
        ("fast", "Fast", "Plain SIFT: about a third of the time to find features")])
    cameras: EnumProperty(name="Cameras", default=DEFAULTS.cameras, items=[
        ("auto", "Automatic", "A camera per photo for photos (a phone's focal length moves with "
                              "its focus), one shared by a video's frames"),
        ("shared", "Shared", "One camera for all photos of one size and lens"),
        ("per-photo", "Per Photo", "A camera (focal length, distortion) for each photo")])
    matching: EnumProperty(name="Matching", default=DEFAULTS.matching, items=[
        ("auto", "Automatic", "Sequential for a video, every pair up to 100 photos, "
                              "retrieval beyond"),
        ("exhaustive", "Every Pair", "Each photo with every other"),
        ("sequential", "Sequential", "Each photo with the next ones in name order"),
        ("retrieval", "Similar Photos", "Each photo with the 20 that look most alike")])
    mapper: EnumProperty(name="Mapper", default=DEFAULTS.mapper, items=[
        ("incremental", "Incremental", "COLMAP's incremental mapper, one photo at a time: the "
                                       "reliable one (the demo placed within 0.5 degrees 12 "
                                       "times in 12)"),
        ("global", "Global", "COLMAP 4's global structure from motion: faster, but it folded "
                             "the demo's ring of photos 2 times in 12")])
    threads: IntProperty(name="Threads", default=0, min=0,
                         description="0: every core but one (Blender keeps one)")
    train_after: BoolProperty(name="Train After", default=False,
                              description="Start training Gaussians on the scene once it is "
                                          "imported")

    interactive: BoolProperty(default=False, options={"HIDDEN", "SKIP_SAVE"})

    needs = (MODULES, FEATURE)
    poll = classmethod(dependencies.poll_needs)
    invoke = JobOperator.invoke_file_browser

    def draw(self, context):
        draw_settings(self.layout, self, ("output", "frames", "max_size", "features", "cameras",
                                          "matching", "mapper", "threads", "train_after"))

    def _source(self) -> Path:
        path = Path(bpy.path.abspath(self.filepath))
        if not path.is_file() or path.suffix.lower() not in VIDEO_SUFFIXES:
            path = path if path.is_dir() else path.parent  # a photo picked: its folder
        return path

    def execute(self, context):
        try:
            colmap_import.require_modules()
        except dependencies.MissingModule as error:
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}
        source = self._source()
        output = Path(bpy.path.abspath(self.output)) if self.output else default_output(source)
        threads = self.threads or (ui_kernel_threads() if self.interactive else 0)
        options = {"frames": self.frames, "max_size": self.max_size, "features": self.features,
                   "cameras": self.cameras, "matching": self.matching, "mapper": self.mapper,
                   "threads": threads}
        steps = reconstruct_steps(source, output, options, {"scene": context.scene})
        train_after = self.train_after

        def finish(running, write):
            job = running.job
            if job.error is not None:
                return "ERROR", f"{source}: {job.error}" if str(source) not in str(job.error) \
                    else str(job.error), None
            if job.result is None:
                return "WARNING", "reconstruction cancelled: the scene is unchanged (running " \
                                  "it again resumes where it stopped)", None
            report, collection = job.result
            level, message = report_message(report)
            if train_after:
                mode = "INVOKE_DEFAULT" if wants_background(bpy.context) else "EXEC_DEFAULT"
                bpy.ops.splat.train(mode, collection=collection.name)
            return level, f"{message}; imported into '{collection.name}'", None

        key = f"reconstruct:{output}"
        return self.run_job(context, OperatorJob(key, "Reconstructing",
                                                 StagedJob(steps, STAGES, weights=WEIGHTS), finish))


def _menu_import(self, context):
    self.layout.operator(SPLAT_OT_import_photos.bl_idname,
                         text="Photos or Video (reconstruct cameras)")


register, unregister = module_registration(
    (SPLAT_OT_import_photos,), menus=[("TOPBAR_MT_file_import", _menu_import)])
