"""Import splats: a finished training job's result, or any Gaussian-splat PLY."""

from __future__ import annotations

import json
import math
from pathlib import Path

import bpy
from bpy_extras.io_utils import ImportHelper

from gsgs_engine import GsgsError
from gsgs_engine.job import Job

from . import background_sphere, node_groups, ops_setup, splat_import
from .ops_common import job_run, report_error

RESULT_COLLECTION = "GS-GS Result"


def _collection(scene, name: str):
    coll = bpy.data.collections.get(name) or bpy.data.collections.new(name)
    if coll.name not in scene.collection.children:
        scene.collection.children.link(coll)
    return coll


def import_ply(scene, path: str | Path, replace_result: bool = True):
    """Import the PLY as the scene's result; with Set Up Rendering on (the default) the scene's render
    settings are made to suit splats. The lines to report (changes, count warning) are in obj["gsgs_report"]."""
    s = scene.gsgs
    if replace_result and s.result_object is not None:
        bpy.data.objects.remove(s.result_object, do_unlink=True)
    obj, seconds = splat_import.import_splats(path, collection=_collection(scene, RESULT_COLLECTION),
                                              max_display=s.max_display, size=s.splat_size)
    obj["gsgs_import_seconds"] = round(seconds, 3)
    s.result_object = obj
    lines = []
    warning = splat_import.count_warning(int(obj["gsgs_count"]), path)
    if warning:
        lines.append("WARNING: " + warning)
    # A new object starts in the scene's colour mode (not a change to report).
    node_groups.set_modifier_input(obj.modifiers[node_groups.MODIFIER_NAME], "Linear Colours",
                                   s.colour_mode == "LINEAR")
    if s.setup_render_on_import:
        lines += [f"splat render set-up: {line}" for line in ops_setup.set_up(scene, s.colour_mode)]
    obj["gsgs_report"] = lines
    return obj


def report_import(op, obj) -> None:
    """The import's Info lines: count and time, the count warning, each render setting changed."""
    op.report({"INFO"}, f"{obj['gsgs_count']} splats in {obj['gsgs_import_seconds']} s")
    for line in obj.get("gsgs_report", []):
        if line.startswith("WARNING: "):
            op.report({"WARNING"}, line[len("WARNING: "):])
        else:
            op.report({"INFO"}, line)


def import_job_result(scene, job_dir: str | Path):
    """The splats of a training job, only once its status is ok."""
    job = Job.open(job_dir)
    status = job.status() or {}
    if status.get("state") != "ok":
        raise GsgsError(f"{job.root}: the job is {status.get('state', 'not finished')}; "
                        "its result is imported only after it finishes successfully")
    ply = job.result_dir / "point_cloud.ply"
    if not ply.is_file():
        raise GsgsError(f"{ply}: missing although the job finished; run the job again")
    obj = import_ply(scene, ply)
    obj["gsgs_job"] = str(job.root)
    import_result_background(scene, job.result_dir, obj)
    fit_result_near(scene, job.result_dir, obj)
    return obj


def result_near(result_dir) -> float | None:
    """The near plane a result's novel views were drawn with, in world units (metrics.json's plan.novel_view_near
    x plan.world_scale), where its effect plan read an inward shell; None otherwise (other rigs draw with the
    renderer's default) or without a readable record."""
    try:
        plan = json.loads((Path(result_dir) / "metrics.json").read_text()).get("plan", {})
        if plan["effects"]["rig"]["value"] != "inward shell":
            return None
        near, scale = float(plan["novel_view_near"]), float(plan.get("world_scale", 1.0))
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    if not (math.isfinite(near) and math.isfinite(scale)) or near <= 0 or scale <= 0:
        return None
    return near * scale


def fit_result_near(scene, result_dir, splats_obj) -> None:
    """An inward shell's result (cameras on the walls they film): the scene's cameras get at least the run's near
    plane as their clip start, so a camera on the shell does not draw the wall's splats around its lens (the
    engine drew its test views so, docs/inward_rigs.md); a line for the import's report per camera changed."""
    near = result_near(result_dir)
    if near is None:
        return
    lines = []
    for cam in [o for o in scene.objects if o.type == "CAMERA"]:
        if cam.data.clip_start < near:
            old, cam.data.clip_start = cam.data.clip_start, near
            lines.append(f"{cam.name} clip start: {old:.4g} -> {near:.4g} (the run's near plane for novel views: "
                         "the wall's splats around a camera on the shell stay out of its image)")
    splats_obj["gsgs_report"] = list(splats_obj.get("gsgs_report", [])) + lines


def import_result_background(scene, result_dir, splats_obj) -> None:
    """The result's learned background sphere (an inward-shell run's wall), replacing an earlier one; a line for
    the import's report. Results without one get nothing (and an earlier sphere is removed with their splats)."""
    for old in [o for o in scene.objects if "gsgs_background_sphere" in o]:
        bpy.data.objects.remove(old, do_unlink=True)
    record = background_sphere.record_of(result_dir)
    if record is None:
        return
    sphere = background_sphere.import_background_sphere(result_dir, record, _collection(scene, RESULT_COLLECTION),
                                                        scene.gsgs.colour_mode)
    lines = [f"background: {sphere.name}, the wall learned behind the splats (radius {record['radius']:.3g})"]
    for cam in [o for o in scene.objects if o.type == "CAMERA"]:
        lines += background_sphere.fit_clip_end(cam, sphere)
    splats_obj["gsgs_report"] = list(splats_obj.get("gsgs_report", [])) + lines


class GSGS_OT_import_result(bpy.types.Operator):
    bl_idname = "gsgs.import_result"
    bl_label = "Import Result"
    bl_description = ("Import the finished training job's splats (replaces the previous result); with Set Up "
                      "Rendering on, the scene's render settings are made to suit splats (each change reported)")
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        run = job_run(context.scene.gsgs.train_job)
        if run is None or run.state != "ok":
            cls.poll_message_set("No successfully finished training job")
            return False
        return True

    def execute(self, context):
        try:
            obj = import_job_result(context.scene, bpy.path.abspath(context.scene.gsgs.train_job))
        except GsgsError as exc:
            return report_error(self, exc)
        report_import(self, obj)
        return {"FINISHED"}


class GSGS_OT_import_splat_ply(bpy.types.Operator, ImportHelper):
    bl_idname = "gsgs.import_splat_ply"
    bl_label = "Import Splat PLY"
    bl_description = "Import any Gaussian-splat PLY (3DGS layout, SH degree 0-3, extra fields kept as attributes)"
    bl_options = {"REGISTER", "UNDO"}

    filename_ext = ".ply"
    filter_glob: bpy.props.StringProperty(default="*.ply", options={"HIDDEN"})

    def execute(self, context):
        try:
            obj = import_ply(context.scene, self.filepath, replace_result=False)
        except GsgsError as exc:
            return report_error(self, exc)
        report_import(self, obj)
        return {"FINISHED"}


CLASSES = (GSGS_OT_import_result, GSGS_OT_import_splat_ply)
