"""Import a multi-view video (synchronised, calibrated cameras) as the training cameras of a 4D job.

The folder is read by the engine's own loaders (gsgs_engine.io.load_scene: a CMU Panoptic capture,
Neural 3D Video, NeRF-synthetic JSON with time), standard library and numpy only, so the add-on
shows exactly the cameras and frames the job will train on. One camera object per training camera
(its pose at the first frame, that frame's image as background); the scene's frame range becomes the
capture's frame ids, which is how an imported 4D result maps the timeline onto the engine's time
(timeline.py). The Train operator then writes a job that names the folder (data.path, train_views,
frames) instead of inline photos.
"""

from __future__ import annotations

from pathlib import Path

import bpy

from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera

from . import camera_convert
from .ops_common import report_error
from .ops_photos import _fresh_collection, set_background_photo

VIDEO_COLLECTION = "GS-GS Video Cameras"
PROP_FROM_VIDEO = "gsgs_video"  # on camera objects an import created (replaced by the next import)


def load_video(folder: str, train_cameras: int, frames: str):
    """The engine's Scene of a multi-view video; GsgsError naming the folder when it is not one."""
    from gsgs_engine.io import load_scene

    path = Path(folder)
    if not path.is_dir():
        raise GsgsError(f"{path}: not a folder; choose the folder of a multi-view video (a Panoptic capture with "
                        "train_meta.json, Neural 3D Video cam00.mp4 ..., or transforms.json with times)")
    if not load_scene(path).has_time:  # images load lazily: reading the layout twice costs no pixels
        raise GsgsError(f"{path}: these views carry no time (a static scene); import photos or use scene cameras "
                        "for it, or choose the folder of a multi-view video")
    return load_scene(path, train_views=train_cameras or None, frames=frames.strip() or None)


def camera_frames(scene) -> tuple[list, list[int]]:
    """(first view of each training camera, in camera order; the capture's frame ids) of a loaded video."""
    first: dict = {}
    for v in scene.train:
        key = v.camera.extra.get("camera_index", v.camera.name)
        if key not in first or v.camera.time < first[key].camera.time:
            first[key] = v
    frames = sorted({int(v.camera.extra.get("frame", 0)) for v in scene.views})
    return [first[k] for k in sorted(first, key=str)], frames


def import_video(scene, folder: str, train_cameras: int, frames: str) -> list:
    """Camera objects of the video's training cameras; the scene's frame range set to the capture's frames."""
    from gsgs_engine.io.world_scale import camera_dicts_to_world

    video = load_video(folder, train_cameras, frames)
    views, frame_ids = camera_frames(video)
    for obj in [o for o in bpy.data.objects if PROP_FROM_VIDEO in o]:  # an earlier import's cameras
        bpy.data.objects.remove(obj, do_unlink=True)
    coll = _fresh_collection(scene, VIDEO_COLLECTION)
    cams = [Camera.from_dict(d) for d in camera_dicts_to_world([v.camera.to_dict() for v in views], video.world_scale)]
    objects = []
    for v, cam in zip(views, cams):
        name = f"cam_{v.camera.extra.get('camera_index', len(objects))}"
        obj = camera_convert.new_camera_object(cam, coll, scene, name=name)
        obj[PROP_FROM_VIDEO] = str(folder)
        if v.image_path is not None and Path(v.image_path).is_file():
            set_background_photo(obj, str(v.image_path))
        objects.append(obj)
    camera_convert.apply_camera_to_object(cams[0], objects[0], scene, set_scene_frame=True)
    scene.frame_start, scene.frame_end = frame_ids[0], frame_ids[-1]
    scene.frame_set(frame_ids[0])
    scene.camera = objects[0]
    s = scene.gsgs
    s.camera_collection = coll
    s.points_object = None
    s.video_source = str(folder)
    s.video_train_cameras = int(train_cameras)
    s.video_frames = frames.strip()
    return objects


def video_job_data(scene) -> dict | None:
    """job.json data of the imported video (None when the training cameras are not a video's)."""
    s = scene.gsgs
    if not s.video_source:
        return None
    data = {"path": str(Path(bpy.path.abspath(s.video_source)).resolve()), "format": "auto",
            "background": [1.0, 1.0, 1.0]}
    if s.video_train_cameras:
        data["train_views"] = int(s.video_train_cameras)
    if s.video_frames:
        data["frames"] = s.video_frames
    return data


class GSGS_OT_import_video(bpy.types.Operator):
    bl_idname = "gsgs.import_video"
    bl_label = "Import Multi-View Video"
    bl_description = ("Read a synchronised multi-view video (CMU Panoptic, Neural 3D Video, or NeRF JSON with times) "
                      "and make its training cameras the scene's; Train then fits a 4D model that plays on the "
                      "timeline")
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        if not context.scene.gsgs.video_dir:
            cls.poll_message_set("Choose the video's folder first")
            return False
        return True

    def execute(self, context):
        s = context.scene.gsgs
        folder = bpy.path.abspath(s.video_dir)
        try:
            cams = import_video(context.scene, folder, s.video_train_cameras, s.video_frames)
        except GsgsError as exc:
            return report_error(self, exc)
        scene = context.scene
        self.report({"INFO"}, f"{len(cams)} training cameras of {Path(folder).name}, frames "
                              f"{scene.frame_start}-{scene.frame_end}")
        return {"FINISHED"}


CLASSES = (GSGS_OT_import_video,)
