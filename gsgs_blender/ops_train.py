"""Train / validate in the background, cancel and resume: the job folder is the only link."""

from __future__ import annotations

from pathlib import Path

import bpy

from gsgs_engine import GsgsError
from gsgs_engine.job import Job, settings_with_preset

from . import camera_convert, pseudo_paths, train_estimate
from .ops_common import job_run, launch, new_job_dir, report_error, scene_callback, stored_path, timeout_property
from .ops_photos import on_sfm_finished, photo_of
from .ops_result import import_job_result
from .ops_video import video_job_data
from .preferences import get_prefs, prior_settings

JOB_KINDS = [("sfm", "Camera Solve", ""), ("train", "Training", ""), ("validate", "Validation", "")]


def training_views(scene) -> list[dict]:
    """The training cameras as job data: Camera.to_dict() + "image" + "split"."""
    objs = pseudo_paths.training_camera_objects(scene)
    if not objs:
        raise GsgsError("no training cameras; import photos (Solve Cameras) or Use Scene Cameras first")
    views = []
    for obj in objs:
        image = photo_of(obj)
        if not image or not Path(image).is_file():
            raise GsgsError(f"camera {obj.name!r}: photo {image or '(none)'} not found; set its background image")
        cam = camera_convert.camera_from_object(obj, scene)
        size = _image_size(image)
        if size is not None and size != (cam.width, cam.height):
            # A scene camera sized by the render settings: scale to the photo when the aspect agrees.
            w, h = size
            if abs(w / h - cam.width / cam.height) > 0.01:
                raise GsgsError(f"camera {obj.name!r}: photo is {w}x{h} but the camera frame is "
                                f"{cam.width}x{cam.height}; set the render resolution to the photo's")
            cam = cam.scaled(w / cam.width)
        views.append({**cam.to_dict(), "image": image, "split": "train"})
    return views


def _image_size(path: str) -> tuple[int, int] | None:
    img = bpy.data.images.load(path, check_existing=True)
    w, h = img.size
    return (int(w), int(h)) if w and h else None


def job_settings(context) -> dict:
    """job.json settings from the Train fields; a chosen preset is recorded and fills what has no field."""
    s = context.scene.gsgs
    settings = {"iters": int(s.iterations), "resolution_scale": float(s.resolution_scale), "max_side": int(s.max_side),
                **prior_settings(get_prefs(context), s.generator, s.rounds)}
    if s.preset != "custom":
        settings["preset"] = s.preset
    return settings_with_preset(settings)


def train_spec(context) -> dict:
    """Job.create keyword arguments of the scene's training job (data, settings, pseudo poses)."""
    scene = context.scene
    s = scene.gsgs
    data = video_job_data(scene)  # an imported multi-view video: the job names its folder
    if data is None:
        data = {"path": ".", "format": "job", "cameras": training_views(scene), "background": [1.0, 1.0, 1.0]}
        points = sparse_points_file(scene)
        if points:
            data["points"] = points  # the solve's sparse points (xyz + rgb PLY), to initialise the splats
    return {
        "data": data,
        "settings": job_settings(context),
        "pseudo_poses": [] if s.video_source else pseudo_paths.poses_from_json(s.pseudo_poses),
        "blender": {"file": bpy.data.filepath, "scene": scene.name},
    }


def sparse_points_file(scene) -> str | None:
    """The camera solve's points.ply, when the points object still sits where the solve put it."""
    import numpy as np

    s = scene.gsgs
    obj = s.points_object
    if not s.sfm_job or obj is None or not np.allclose(np.asarray(obj.matrix_world), np.eye(4)):
        return None
    path = Path(bpy.path.abspath(s.sfm_job)) / "result" / "points.ply"
    return str(path) if path.is_file() else None


def probe_machine(context) -> dict | None:
    """Probe this machine's speed for the time estimate (train_estimate.refresh_probe: about 2 s, at most every
    PROBE_MAX_AGE_S) when the job will train here on the CPU; None when it will not or cannot be probed."""
    prefs = get_prefs(context)
    if getattr(prefs, "run_on", "local") != "local" or getattr(prefs, "device", "auto") == "cuda":
        return None
    python = bpy.path.abspath(prefs.python_path) if prefs.python_path else ""
    engine_root = bpy.path.abspath(prefs.engine_root) if prefs.engine_root else None
    return train_estimate.refresh_probe(python, engine_root)


def _on_train_finished(scene, run) -> None:
    if run.state == "ok":
        print(f"gsgs: time estimate {train_estimate.learn_from_job(run.job_dir)}", flush=True)
        obj = import_job_result(scene, run.job_dir)
        report = list(obj.get("gsgs_report", []))
        warnings = [line for line in report if line.startswith("WARNING: ")]
        run.message = f"{run.message} — imported {obj['gsgs_count']} splats" + "".join(f"; {w}" for w in warnings)
        for line in report:  # the job's callback has no operator to report through: the console keeps them
            print(f"gsgs: {line}", flush=True)


CALLBACKS = {"train": _on_train_finished, "validate": None}


def _running(path: str) -> bool:
    run = job_run(path)
    return run is not None and run.state == "running"


class GSGS_OT_train(bpy.types.Operator):
    bl_idname = "gsgs.train"
    bl_label = "Train"
    bl_description = ("Write a training job (cameras, photos, pseudo poses, settings) and run the engine in the "
                      "background; the result is imported when it finishes")
    bl_options = {"REGISTER"}

    timeout: timeout_property()

    @classmethod
    def poll(cls, context):
        if not pseudo_paths.training_camera_objects(context.scene):
            cls.poll_message_set("No training cameras: solve cameras or use scene cameras first")
            return False
        if _running(context.scene.gsgs.train_job):
            cls.poll_message_set("Training is running; cancel it first")
            return False
        return True

    def execute(self, context):
        scene = context.scene
        try:
            job = Job.create(new_job_dir(context, "train"), "train", **train_spec(context))
            probe_machine(context)
            inputs = train_estimate.job_estimate_inputs(scene)
            device = train_estimate.device_of(get_prefs(context))
            # stated before the job runs (headless: before it ends)
            estimate = train_estimate.estimate_text(scene, inputs, device)
            if inputs is not None:  # what is estimated now; the finished job's time corrects later estimates
                train_estimate.write_job_estimate(job.root, **inputs, device=device)
            scene.gsgs.train_job = stored_path(job.root)
            run = launch(context, job, on_finish=scene_callback(scene.name, _on_train_finished), timeout=self.timeout)
        except GsgsError as exc:
            return report_error(self, exc)
        if run.finished and run.state != "ok":
            return report_error(self, GsgsError(f"training {run.state}: {run.message}"))
        self.report({"INFO"}, run.message if run.finished else
                    f"training started: {job.root}" + (f" (estimated {estimate})" if estimate else ""))
        return {"FINISHED"}


class GSGS_OT_validate(bpy.types.Operator):
    bl_idname = "gsgs.validate"
    bl_label = "Run Validation"
    bl_description = ("Train on a few views of a dataset with held-out test views and measure PSNR / SSIM / LPIPS "
                      "on the test views, in the background")
    bl_options = {"REGISTER"}

    timeout: timeout_property()

    @classmethod
    def poll(cls, context):
        s = context.scene.gsgs
        if not s.validate_source:
            cls.poll_message_set("Choose a dataset folder first")
            return False
        if _running(s.validate_job):
            cls.poll_message_set("Validation is running; cancel it first")
            return False
        return True

    def execute(self, context):
        s = context.scene.gsgs
        source = Path(bpy.path.abspath(s.validate_source))
        if not source.exists():
            return report_error(self, GsgsError(f"{source}: no such dataset folder"))
        try:
            job = Job.create(new_job_dir(context, "validate"), "validate",
                             data={"path": str(source), "format": "auto", "train_views": int(s.validate_views)},
                             settings=job_settings(context))
            s.validate_job = stored_path(job.root)
            run = launch(context, job, timeout=self.timeout)
        except GsgsError as exc:
            return report_error(self, exc)
        if run.finished and run.state != "ok":
            return report_error(self, GsgsError(f"validation {run.state}: {run.message}"))
        self.report({"INFO"}, run.message if run.finished else f"validation started: {job.root}")
        return {"FINISHED"}


class GSGS_OT_cancel_job(bpy.types.Operator):
    bl_idname = "gsgs.cancel_job"
    bl_label = "Cancel"
    bl_description = "Ask the running job to stop (it saves a checkpoint); it is terminated if it does not stop soon"

    kind: bpy.props.EnumProperty(items=JOB_KINDS, default="train")

    def execute(self, context):
        run = job_run(getattr(context.scene.gsgs, f"{self.kind}_job"))
        if run is None or run.state != "running":
            self.report({"WARNING"}, "nothing is running")
            return {"CANCELLED"}
        run.request_cancel()
        self.report({"INFO"}, "cancel requested")
        return {"FINISHED"}


class GSGS_OT_resume_job(bpy.types.Operator):
    bl_idname = "gsgs.resume_job"
    bl_label = "Resume"
    bl_description = "Run the job folder again; training continues from its last checkpoint"

    kind: bpy.props.EnumProperty(items=JOB_KINDS, default="train")

    timeout: timeout_property()

    def execute(self, context):
        scene = context.scene
        path = getattr(scene.gsgs, f"{self.kind}_job")
        run = job_run(path)
        if run is None:
            return report_error(self, GsgsError(f"{path or 'job'}: no job folder to resume"))
        if run.state == "running":
            return report_error(self, GsgsError("the job is already running"))
        callback = None
        if self.kind == "sfm":
            callback = scene_callback(scene.name, on_sfm_finished)
        elif CALLBACKS.get(self.kind):
            callback = scene_callback(scene.name, CALLBACKS[self.kind])
        try:
            run = launch(context, Job.open(run.job_dir), on_finish=callback, timeout=self.timeout)
        except GsgsError as exc:
            return report_error(self, exc)
        self.report({"INFO"}, run.message if run.finished else "resumed")
        return {"FINISHED"}


CLASSES = (GSGS_OT_train, GSGS_OT_validate, GSGS_OT_cancel_job, GSGS_OT_resume_job)
