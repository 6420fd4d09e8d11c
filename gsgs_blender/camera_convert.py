"""Blender camera objects <-> gsgs_engine.cameras.Camera (OpenCV convention).

The maths lives in the engine's numpy-only camera_from_blender / blender_from_camera (one
tested module for every convention); this file only reads and writes bpy data with it.
Each camera object also keeps its own image size and pixel aspect as custom properties,
because a Blender scene has one render resolution but photos may differ.
"""

from __future__ import annotations

import math

import numpy as np

from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera, blender_from_camera, camera_from_blender

DEFAULT_SENSOR_MM = 36.0

PROP_WIDTH, PROP_HEIGHT, PROP_ASPECT, PROP_IMAGE = "gsgs_width", "gsgs_height", "gsgs_pixel_aspect", "gsgs_image"


def frame_of(obj, scene) -> tuple[int, int, float, float]:
    """(width, height, pixel_aspect_x, pixel_aspect_y) of a camera object: its own, else the scene's."""
    render = scene.render
    if PROP_WIDTH in obj and PROP_HEIGHT in obj:
        width, height = int(obj[PROP_WIDTH]), int(obj[PROP_HEIGHT])
    else:
        # Blender's BKE_render_resolution truncates the percentage-scaled size.
        width = render.resolution_x * render.resolution_percentage // 100
        height = render.resolution_y * render.resolution_percentage // 100
    if PROP_ASPECT in obj:
        ax, ay = (float(v) for v in obj[PROP_ASPECT])
    else:
        ax, ay = float(render.pixel_aspect_x), float(render.pixel_aspect_y)
    return width, height, ax, ay


def camera_from_object(obj, scene, name: str | None = None) -> Camera:
    """A Blender camera object -> Camera (pose from matrix_world, intrinsics from lens/sensor/shift)."""
    if obj is None or obj.type != "CAMERA":
        raise GsgsError(f"{getattr(obj, 'name', obj)!r} is not a camera object; select camera objects")
    data = obj.data
    if data.type != "PERSP":
        raise GsgsError(f"camera {obj.name!r} is {data.type.lower()}; set its lens type to Perspective")
    width, height, ax, ay = frame_of(obj, scene)
    return camera_from_blender(np.asarray(obj.matrix_world), lens=data.lens, sensor_width=data.sensor_width,
                               sensor_height=data.sensor_height, sensor_fit=data.sensor_fit,
                               shift_x=data.shift_x, shift_y=data.shift_y, resolution_x=width,
                               resolution_y=height, resolution_percentage=100, pixel_aspect_x=ax,
                               pixel_aspect_y=ay, clip_start=float(data.clip_start), clip_end=float(data.clip_end),
                               name=name if name is not None else obj.name)


def apply_camera_to_object(cam: Camera, obj, scene=None, set_scene_frame: bool = False) -> None:
    """Set a Blender camera object's pose and lens so it sees exactly what `cam` sees."""
    # Written with an explicit fit (the one AUTO picks for this frame), so a later change of the
    # scene resolution cannot silently swap which side the sensor spans.
    fit = "HORIZONTAL" if cam.width * max(1.0, cam.fx / cam.fy) >= cam.height * max(1.0, cam.fy / cam.fx) \
        else "VERTICAL"
    settings = blender_from_camera(cam, sensor_width=DEFAULT_SENSOR_MM, sensor_height=DEFAULT_SENSOR_MM,
                                   sensor_fit=fit)
    data = obj.data
    data.type = "PERSP"
    data.lens_unit = "MILLIMETERS"
    data.sensor_width = settings["sensor_width"]
    data.sensor_height = settings["sensor_height"]
    data.sensor_fit = settings["sensor_fit"]
    data.lens = settings["lens"]
    data.shift_x = settings["shift_x"]
    data.shift_y = settings["shift_y"]
    if cam.near is not None and cam.near > 0:
        data.clip_start = cam.near
    if cam.far is not None and cam.far > (cam.near or 0):
        data.clip_end = cam.far
    obj[PROP_WIDTH] = int(cam.width)
    obj[PROP_HEIGHT] = int(cam.height)
    obj[PROP_ASPECT] = [settings["pixel_aspect_x"], settings["pixel_aspect_y"]]
    obj.matrix_world = _to_blender_matrix(np.asarray(settings["matrix_world"]))
    if set_scene_frame and scene is not None:
        render = scene.render
        render.resolution_x = settings["resolution_x"]
        render.resolution_y = settings["resolution_y"]
        render.resolution_percentage = 100
        render.pixel_aspect_x = settings["pixel_aspect_x"]
        render.pixel_aspect_y = settings["pixel_aspect_y"]


def new_camera_object(cam: Camera, collection, scene=None, name: str | None = None):
    """Create a camera object for `cam` in `collection` and return it."""
    import bpy

    label = name or cam.name or "gsgs_camera"
    data = bpy.data.cameras.new(label)
    obj = bpy.data.objects.new(label, data)
    collection.objects.link(obj)
    apply_camera_to_object(cam, obj, scene)
    data.display_size = 0.25  # Blender's default 1.0 swamps a small reconstructed scene
    return obj


def _to_blender_matrix(m: np.ndarray):
    from mathutils import Matrix

    return Matrix([[float(v) for v in row] for row in m])


def fov_degrees(cam: Camera) -> tuple[float, float]:
    return math.degrees(cam.fov_x), math.degrees(cam.fov_y)
