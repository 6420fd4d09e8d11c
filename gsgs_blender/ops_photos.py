"""Photos -> cameras: an SfM job in the background, then camera objects and sparse points;
or known poses from cameras already in the scene."""

from __future__ import annotations

import json
from pathlib import Path

import bpy
import numpy as np

from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera
from gsgs_engine.job import Job

from . import camera_convert
from .ops_common import job_run, launch, new_job_dir, report_error, scene_callback, stored_path, timeout_property

CAMERA_COLLECTION = "GS-GS Cameras"
POINTS_NAME = "GS-GS Sparse Points"
PROP_FROM_SFM = "gsgs_sfm_job"  # on camera objects a solve created (replaced by the next solve)


def photo_of(obj) -> str | None:
    """The photo a training camera shows: its gsgs_image property, else its first background image."""
    path = obj.get(camera_convert.PROP_IMAGE)
    if path:
        return bpy.path.abspath(path)
    for bg in obj.data.background_images:
        if bg.image is not None and bg.image.filepath:
            return bpy.path.abspath(bg.image.filepath)
    return None


def set_background_photo(obj, path: str) -> None:
    image = bpy.data.images.load(path, check_existing=True)
    data = obj.data
    bg = data.background_images[0] if len(data.background_images) else data.background_images.new()
    bg.image = image
    bg.frame_method = "STRETCH"  # the photo spans exactly the camera frame (shift and aspect included)
    bg.alpha = 0.8
    data.show_background_images = True
    obj[camera_convert.PROP_IMAGE] = path


def _fresh_collection(scene, name: str):
    """The collection emptied of an earlier solve's cameras; the user's own objects are only unlinked."""
    coll = bpy.data.collections.get(name)
    if coll is not None:
        for obj in list(coll.objects):
            if PROP_FROM_SFM in obj or obj.name == POINTS_NAME:
                bpy.data.objects.remove(obj, do_unlink=True)
            elif len(obj.users_collection) > 1:
                coll.objects.unlink(obj)
            else:  # keep it in the scene, out of the training set
                scene.collection.objects.link(obj)
                coll.objects.unlink(obj)
    else:
        coll = bpy.data.collections.new(name)
    if coll.name not in scene.collection.children:
        scene.collection.children.link(coll)
    return coll


def read_cameras_json(path: Path) -> list[tuple[Camera, str]]:
    """result/cameras.json of an SfM job: a list of Camera.to_dict() entries plus "image"."""
    try:
        entries = json.loads(path.read_text())
    except FileNotFoundError as exc:
        raise GsgsError(f"{path}: missing; the SfM job did not finish (see its log.txt)") from exc
    except json.JSONDecodeError as exc:
        raise GsgsError(f"{path}: not valid JSON ({exc}); run the SfM job again") from exc
    if isinstance(entries, dict):
        entries = entries.get("cameras", [])
    out = []
    for i, entry in enumerate(entries):
        cam = Camera.from_dict(entry, source=f"{path}[{i}]")
        image = entry.get("image", "")
        if image and not Path(image).is_absolute():
            image = str((path.parent / image).resolve())
        out.append((cam, image))
    if not out:
        raise GsgsError(f"{path}: no cameras; SfM registered no photo (see the job's log.txt)")
    return out


def points_object(scene, positions: np.ndarray, colors: np.ndarray | None, collection):
    """A vertices-only mesh of sparse points with a `color` attribute (shown by the viewport's
    attribute colour in solid mode)."""
    old = bpy.data.objects.get(POINTS_NAME)
    if old is not None:
        bpy.data.objects.remove(old, do_unlink=True)
    mesh = bpy.data.meshes.new(POINTS_NAME)
    mesh.vertices.add(len(positions))
    mesh.attributes["position"].data.foreach_set("vector", np.asarray(positions, np.float32).ravel())
    if colors is not None and len(colors) == len(positions):
        rgba = np.concatenate([np.asarray(colors, np.float32), np.ones((len(colors), 1), np.float32)], 1)
        mesh.color_attributes.new("color", "FLOAT_COLOR", "POINT").data.foreach_set("color", rgba.ravel())
    mesh.update()
    obj = bpy.data.objects.new(POINTS_NAME, mesh)
    collection.objects.link(obj)
    return obj


def load_sfm_result(scene, job_dir: str | Path) -> tuple[list, object | None]:
    """Camera objects (with their photos) and the sparse points of a finished SfM job."""
    from gsgs_engine.io.ply import read_ply_vertices

    job = Job.open(job_dir)
    status = job.status() or {}
    if status.get("state") != "ok":
        raise GsgsError(f"{job.root}: the SfM job is {status.get('state', 'not finished')}: "
                        f"{status.get('message', '')}; run it again")
    cams = read_cameras_json(job.result_dir / "cameras.json")
    coll = _fresh_collection(scene, CAMERA_COLLECTION)
    objects = []
    for i, (cam, image) in enumerate(cams):
        obj = camera_convert.new_camera_object(cam, coll, scene, name=cam.name or f"view_{i:03d}")
        obj[PROP_FROM_SFM] = str(job.root)
        if image:
            if not Path(image).is_file():
                raise GsgsError(f"{image}: photo of camera {cam.name!r} is missing; run the SfM job again")
            set_background_photo(obj, image)
        objects.append(obj)
    before = (scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage)
    camera_convert.apply_camera_to_object(cams[0][0], objects[0], scene, set_scene_frame=True)
    after = (scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage)
    # The render frame follows the photos so the cameras show them undistorted; said, never silent.
    scene.gsgs["resolution_note"] = "" if before == after else (
        f"render resolution set to the photos' {after[0]}x{after[1]} at {after[2]}% "
        f"(was {before[0]}x{before[1]} at {before[2]}%)")
    scene.camera = objects[0]
    scene.gsgs.camera_collection = coll
    scene.gsgs.video_source = ""  # the training cameras are photos now
    pts_obj = None
    ply = job.result_dir / "points.ply"
    if ply.is_file():
        cols = read_ply_vertices(ply)
        pos = np.stack([cols["x"], cols["y"], cols["z"]], axis=1)
        rgb = None
        if all(k in cols for k in ("red", "green", "blue")):
            rgb = np.stack([cols["red"], cols["green"], cols["blue"]], axis=1).astype(np.float32) / 255.0
        pts_obj = points_object(scene, pos, rgb, coll)
        scene.gsgs.points_object = pts_obj
    return objects, pts_obj


class GSGS_OT_import_photos(bpy.types.Operator):
    bl_idname = "gsgs.import_photos"
    bl_label = "Solve Cameras"
    bl_description = ("Run structure from motion on the photos folder in the background, then create a camera "
                      "per photo (photo as background) and the sparse points")
    bl_options = {"REGISTER"}

    timeout: timeout_property()

    @classmethod
    def poll(cls, context):
        settings = context.scene.gsgs
        if not settings.photos_dir:
            cls.poll_message_set("Choose a photos folder first")
            return False
        run = job_run(settings.sfm_job)
        if run is not None and run.state == "running":
            cls.poll_message_set("The camera solve is running; cancel it first")
            return False
        return True

    def execute(self, context):
        scene = context.scene
        settings = scene.gsgs
        photos = Path(bpy.path.abspath(settings.photos_dir))
        if not photos.is_dir():
            return report_error(self, GsgsError(f"{photos}: not a folder; choose the folder that holds the photos"))
        try:
            job = Job.create(new_job_dir(context, "sfm"), "sfm", data={"photos": str(photos)},
                             settings={"max_image_size": settings.max_image_size},
                             blender={"file": bpy.data.filepath, "scene": scene.name})
            settings.sfm_job = stored_path(job.root)
            run = launch(context, job, on_finish=scene_callback(scene.name, on_sfm_finished), timeout=self.timeout)
        except GsgsError as exc:
            return report_error(self, exc)
        if run.finished and run.state != "ok":
            return report_error(self, GsgsError(f"camera solve {run.state}: {run.message}"))
        self.report({"INFO"}, f"camera solve started: {job.root}" if not run.finished else run.message)
        return {"FINISHED"}


def on_sfm_finished(scene, run) -> None:
    if run.state == "ok":
        cams, _ = load_sfm_result(scene, run.job_dir)
        note = scene.gsgs.get("resolution_note", "")
        run.message = f"{run.message} — {len(cams)} cameras imported" + (f"; {note}" if note else "")
        if note:
            print(f"gsgs: {note}", flush=True)


class GSGS_OT_load_sfm_result(bpy.types.Operator):
    bl_idname = "gsgs.load_sfm_result"
    bl_label = "Load Cameras"
    bl_description = "Create the cameras and sparse points of the finished camera solve again (replaces them)"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        run = job_run(context.scene.gsgs.sfm_job)
        if run is None or run.state != "ok":
            cls.poll_message_set("No finished camera solve in this scene")
            return False
        return True

    def execute(self, context):
        try:
            cams, _ = load_sfm_result(context.scene, bpy.path.abspath(context.scene.gsgs.sfm_job))
        except GsgsError as exc:
            return report_error(self, exc)
        self.report({"INFO"}, f"{len(cams)} cameras loaded")
        note = context.scene.gsgs.get("resolution_note", "")
        if note:
            self.report({"WARNING"}, note)
        return {"FINISHED"}


class GSGS_OT_use_scene_cameras(bpy.types.Operator):
    bl_idname = "gsgs.use_scene_cameras"
    bl_label = "Use Scene Cameras"
    bl_description = ("Train from cameras already in the scene (known poses): the selected cameras, or all, each "
                      "with its photo as a background image")
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        if not any(o.type == "CAMERA" for o in context.scene.objects):
            cls.poll_message_set("The scene has no cameras")
            return False
        return True

    def execute(self, context):
        scene = context.scene
        cams = [o for o in context.selected_objects if o.type == "CAMERA"] or \
               [o for o in scene.objects if o.type == "CAMERA"]
        missing = [o.name for o in cams if not photo_of(o)]
        if missing:
            return report_error(self, GsgsError(
                f"cameras without a photo: {', '.join(missing[:5])}; give each a background image (its photo)"))
        coll = bpy.data.collections.get(CAMERA_COLLECTION) or bpy.data.collections.new(CAMERA_COLLECTION)
        if coll.name not in scene.collection.children:
            scene.collection.children.link(coll)
        for obj in cams:
            if obj.name not in coll.objects:
                coll.objects.link(obj)
            obj[camera_convert.PROP_IMAGE] = photo_of(obj)
        for obj in list(coll.objects):
            if obj.type == "CAMERA" and obj not in cams and len(obj.users_collection) > 1:
                coll.objects.unlink(obj)  # no longer a training view (still in its other collections)
        scene.gsgs.camera_collection = coll
        scene.gsgs.video_source = ""  # the training cameras are these cameras' photos now
        self.report({"INFO"}, f"{len(cams)} training cameras")
        return {"FINISHED"}


CLASSES = (GSGS_OT_import_photos, GSGS_OT_load_sfm_result, GSGS_OT_use_scene_cameras)
