"""The GS-GS sidebar (View3D > N panel > GS-GS): Photos, Cameras, Pseudo Paths, Train, Result, Validate."""

from __future__ import annotations

import json
from pathlib import Path

import bpy
from gsgs_engine import presets

from . import job_runner, pseudo_paths, train_estimate
from .ops_common import job_run
from .preferences import get_prefs


def draw_job(layout, path: str, kind: str) -> None:
    """Phase, progress bar, losses, ETA; Cancel while running; Resume and the log tail after a failure."""
    run = job_run(path)
    if run is None:
        if path:
            layout.label(text=f"job folder missing: {path}", icon="ERROR")
        return
    info = run.summary()
    box = layout.box()
    if run.state == "running":
        text = f"{info['phase']}  {info['step']}/{info['total']}" if info["total"] else info["phase"]
        box.progress(factor=info["progress"], type="BAR", text=text)
        if info["losses"]:
            box.label(text=info["losses"])
        if info["eta"]:
            box.label(text=f"ETA {info['eta']}", icon="TIME")
        if info["message"]:
            box.label(text=info["message"])
        box.operator("gsgs.cancel_job", icon="CANCEL").kind = kind
        return
    icon = {"ok": "CHECKMARK", "error": "ERROR", "cancelled": "CANCEL"}.get(run.state, "QUESTION")
    box.label(text=f"{kind}: {run.state}", icon=icon)
    for line in _wrap(info["message"], 60)[:4]:
        box.label(text=line)
    if run.state == "error":
        tail = job_runner.log_tail(run.job_dir, lines=6)
        if tail:
            col = box.column(align=True)
            col.scale_y = 0.7
            for line in tail.splitlines():
                col.label(text=line[-90:])
    if run.state in ("error", "cancelled", "unknown"):
        box.operator("gsgs.resume_job", icon="PLAY").kind = kind


def _wrap(text: str, width: int) -> list[str]:
    words, lines, line = (text or "").split(), [], ""
    for w in words:
        if len(line) + len(w) + 1 > width and line:
            lines.append(line)
            line = w
        else:
            line = f"{line} {w}".strip()
    if line:
        lines.append(line)
    return lines


class _GsgsPanel:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "GS-GS"


class GSGS_PT_photos(_GsgsPanel, bpy.types.Panel):
    bl_label = "Photos"
    bl_idname = "GSGS_PT_photos"
    bl_order = 0

    def draw(self, context):
        s = context.scene.gsgs
        layout = self.layout
        layout.prop(s, "photos_dir")
        layout.prop(s, "max_image_size")
        layout.operator("gsgs.import_photos", icon="IMPORT")
        draw_job(layout, s.sfm_job, "sfm")
        box = layout.box()  # or a synchronised multi-view video with its calibration: a 4D job
        box.prop(s, "video_dir")
        row = box.row(align=True)
        row.prop(s, "video_train_cameras")
        row.prop(s, "video_frames")
        box.operator("gsgs.import_video", icon="SEQUENCE")
        if s.video_source:
            box.label(text=f"Training on {Path(s.video_source).name} (4D)", icon="TIME")


class GSGS_PT_cameras(_GsgsPanel, bpy.types.Panel):
    bl_label = "Cameras"
    bl_idname = "GSGS_PT_cameras"
    bl_order = 1

    def draw(self, context):
        s = context.scene.gsgs
        layout = self.layout
        cams = pseudo_paths.training_camera_objects(context.scene)
        layout.prop(s, "camera_collection")
        layout.label(text=f"{len(cams)} training cameras", icon="CAMERA_DATA")
        layout.prop(s, "points_object")
        row = layout.row(align=True)
        row.operator("gsgs.use_scene_cameras", icon="OUTLINER_OB_CAMERA")
        row.operator("gsgs.load_sfm_result", icon="FILE_REFRESH")


class GSGS_PT_pseudo(_GsgsPanel, bpy.types.Panel):
    bl_label = "Pseudo Paths"
    bl_idname = "GSGS_PT_pseudo"
    bl_order = 2

    def draw(self, context):
        s = context.scene.gsgs
        layout = self.layout
        layout.operator("gsgs.make_pseudo_path", icon="CURVE_PATH")
        layout.prop(s, "pseudo_curve")
        layout.prop(s, "pseudo_count")
        layout.prop(s, "pseudo_orientation")
        row = layout.row(align=True)
        row.operator("gsgs.sample_pseudo_poses", icon="CAMERA_STEREO")
        row.operator("gsgs.clear_pseudo_poses", icon="X")
        count = len(pseudo_paths.poses_from_json(s.pseudo_poses))
        layout.prop(s, "show_frusta", text=f"Show {count} Frusta")


class GSGS_PT_train(_GsgsPanel, bpy.types.Panel):
    bl_label = "Train"
    bl_idname = "GSGS_PT_train"
    bl_order = 3

    def draw(self, context):
        s = context.scene.gsgs
        layout = self.layout
        layout.prop(s, "preset")
        if s.preset != "custom":
            p = presets.PRESETS[s.preset]
            layout.label(text=f"{p['pseudo_views']} pseudo views, SH {p['sh_degree']}, backend {p['backend']}",
                         icon="PRESET")
        col = layout.column(align=True)
        col.prop(s, "iterations")
        col.prop(s, "rounds")
        col.prop(s, "resolution_scale")
        col.prop(s, "max_side")
        col.prop(s, "generator")
        poses = len(pseudo_paths.poses_from_json(s.pseudo_poses))
        if poses and s.generator == "none":
            layout.label(text=f"The {poses} path poses are unused: choose a Generator", icon="INFO")
        estimate = train_estimate.estimate_text(context.scene, device=train_estimate.device_of(get_prefs(context)))
        if estimate:
            layout.label(text=f"Estimated: {estimate}", icon="TIME")
        layout.operator("gsgs.train", icon="PLAY")
        draw_job(layout, s.train_job, "train")


class GSGS_PT_result(_GsgsPanel, bpy.types.Panel):
    bl_label = "Result"
    bl_idname = "GSGS_PT_result"
    bl_order = 4

    def draw(self, context):
        s = context.scene.gsgs
        layout = self.layout
        row = layout.row(align=True)
        row.operator("gsgs.import_result", icon="IMPORT")
        row.operator("gsgs.import_splat_ply", icon="FILE_FOLDER", text="PLY...")
        layout.prop(s, "result_object")
        obj = s.result_object
        if obj is not None and "gsgs_count" in obj:
            layout.label(text=f"{obj['gsgs_count']:,} splats, SH degree {obj.get('gsgs_sh_degree', 0)}")
            if obj.get("gsgs_4d"):
                layout.label(text=f"4D: plays on the timeline (frames {obj.get('gsgs_frame_start')}-"
                                  f"{obj.get('gsgs_frame_end')})", icon="TIME")
            elif "gsgs_temporal_fields" in obj:
                layout.label(text="Time fields kept as attributes (not a gsgs 4D result: no playback)", icon="TIME")
        layout.prop(s, "max_display")
        layout.prop(s, "splat_size")
        row = layout.row(align=True)
        row.prop(s, "setup_render_on_import")
        row.prop(s, "colour_mode", text="")
        layout.operator("gsgs.setup_splat_render", icon="SCENE").colour_mode = s.colour_mode
        metrics = _metrics(s.train_job)
        if metrics:
            layout.label(text=metrics)


class GSGS_PT_validate(_GsgsPanel, bpy.types.Panel):
    bl_label = "Validate"
    bl_idname = "GSGS_PT_validate"
    bl_order = 5
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        s = context.scene.gsgs
        layout = self.layout
        layout.prop(s, "validate_source")
        layout.prop(s, "validate_views")
        layout.operator("gsgs.validate", icon="CHECKMARK")
        draw_job(layout, s.validate_job, "validate")
        metrics = _metrics(s.validate_job)
        if metrics:
            layout.label(text=metrics)


def _metrics(job_path: str) -> str:
    """PSNR / SSIM / LPIPS of a job's result/metrics.json, as measured (LPIPS may be absent)."""
    if not job_path:
        return ""
    path = Path(bpy.path.abspath(job_path)) / "result" / "metrics.json"
    try:
        m = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return ""
    parts = []
    for key, fmt in (("psnr", "PSNR {:.2f}"), ("ssim", "SSIM {:.3f}"), ("lpips", "LPIPS {:.3f}")):
        value = m.get(key)
        if isinstance(value, (int, float)):
            parts.append(fmt.format(value))
    return "  ".join(parts)


CLASSES = (GSGS_PT_photos, GSGS_PT_cameras, GSGS_PT_pseudo, GSGS_PT_train, GSGS_PT_result, GSGS_PT_validate)
