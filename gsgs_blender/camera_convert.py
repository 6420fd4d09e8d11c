"""Blender camera objects <-> gsgs_engine.cameras.Camera (OpenCV convention).

The maths follows Blender's own view-plane computation (BKE_camera_params_compute_viewplane):
the sensor fit picks which image side the sensor size spans, pixel aspect stretches y, and
shift_x / shift_y move the view plane in units of that side. The pure functions here take
and return plain numbers so tests check them without Blender; the `*_object` functions
apply them to bpy data.
"""

from __future__ import annotations

import math

import numpy as np

from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera

# Blender's camera looks down -Z with +Y up; OpenCV's looks down +Z with +Y down.
BLENDER_TO_OPENCV_AXES = np.diag([1.0, -1.0, -1.0])
DEFAULT_SENSOR_MM = 36.0


def _effective_fit(sensor_fit: str, width: float, height: float, aspect_x: float, aspect_y: float) -> str:
    """AUTO resolves to the longer side of the (pixel-aspect corrected) frame, as in Blender."""
    if sensor_fit == "AUTO":
        return "HORIZONTAL" if aspect_x * width >= aspect_y * height else "VERTICAL"
    if sensor_fit not in ("HORIZONTAL", "VERTICAL"):
        raise GsgsError(f"unknown Blender sensor fit {sensor_fit!r}; use AUTO, HORIZONTAL or VERTICAL")
    return sensor_fit


def intrinsics_from_blender(lens: float, sensor_width: float, sensor_height: float, sensor_fit: str,
                            shift_x: float, shift_y: float, width: int, height: int,
                            pixel_aspect_x: float = 1.0, pixel_aspect_y: float = 1.0) -> tuple[float, float, float, float]:
    """Blender lens/sensor/shift settings of a width x height frame -> (fx, fy, cx, cy) in pixels."""
    fit = _effective_fit(sensor_fit, width, height, pixel_aspect_x, pixel_aspect_y)
    # AUTO always measures sensor_width (Blender ignores sensor_height unless the fit is VERTICAL).
    sensor = sensor_height if sensor_fit == "VERTICAL" else sensor_width
    ycor = pixel_aspect_y / pixel_aspect_x
    viewfac = width if fit == "HORIZONTAL" else ycor * height
    fx = lens * viewfac / sensor
    fy = fx / ycor
    cx = 0.5 * width - shift_x * viewfac
    cy = 0.5 * height + shift_y * viewfac / ycor
    return fx, fy, cx, cy


def blender_from_intrinsics(fx: float, fy: float, cx: float, cy: float, width: int, height: int,
                            sensor_mm: float = DEFAULT_SENSOR_MM) -> dict:
    """(fx, fy, cx, cy) of a width x height image -> Blender camera and render settings.

    Pixel aspect is >= 1 in Blender, so the smaller focal length's axis gets aspect 1. The
    sensor fit is written explicitly (the one AUTO would pick) so later resolution edits do
    not silently swap the measured side.
    """
    if fx <= 0 or fy <= 0:
        raise GsgsError(f"camera focal lengths must be positive (fx={fx}, fy={fy})")
    aspect_x, aspect_y = (fy / fx, 1.0) if fy >= fx else (1.0, fx / fy)
    ycor = aspect_y / aspect_x  # == fx / fy
    fit = _effective_fit("AUTO", width, height, aspect_x, aspect_y)
    viewfac = width if fit == "HORIZONTAL" else ycor * height
    lens = fx * sensor_mm / viewfac
    return {
        "lens": lens,
        "sensor_width": sensor_mm,
        "sensor_height": sensor_mm,
        "sensor_fit": fit,
        "shift_x": (0.5 * width - cx) / viewfac,
        "shift_y": (cy - 0.5 * height) * ycor / viewfac,
        "resolution_x": int(width),
        "resolution_y": int(height),
        "pixel_aspect_x": aspect_x,
        "pixel_aspect_y": aspect_y,
    }


def pose_from_blender_matrix(matrix_world) -> tuple[np.ndarray, np.ndarray]:
    """Blender camera-to-world 4x4 (any object scale) -> OpenCV world-to-camera (R, t)."""
    m = np.asarray(matrix_world, dtype=np.float64).reshape(4, 4)
    rot = m[:3, :3]
    norms = np.linalg.norm(rot, axis=0)
    if np.any(norms < 1e-12):
        raise GsgsError("camera object has a zero scale; set its scale back to 1")
    rot = rot / norms  # object scale does not change where a camera looks
    c2w_cv = rot @ BLENDER_TO_OPENCV_AXES
    R = c2w_cv.T
    t = -R @ m[:3, 3]
    return R, t


def blender_matrix_from_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """OpenCV world-to-camera (R, t) -> Blender camera-to-world 4x4."""
    R = np.asarray(R, dtype=np.float64).reshape(3, 3)
    t = np.asarray(t, dtype=np.float64).reshape(3)
    m = np.eye(4)
    m[:3, :3] = R.T @ BLENDER_TO_OPENCV_AXES
    m[:3, 3] = -R.T @ t
    return m


# -- bpy adapters ---------------------------------------------------------------------------
# Per-object image size and pixel aspect, so cameras with different photos keep their own
# intrinsics even though a Blender scene has one render resolution.
PROP_WIDTH, PROP_HEIGHT, PROP_ASPECT, PROP_IMAGE = "gsgs_width", "gsgs_height", "gsgs_pixel_aspect", "gsgs_image"


def frame_of(obj, scene) -> tuple[int, int, float, float]:
    """(width, height, pixel_aspect_x, pixel_aspect_y) of a camera object: its own, else the scene's."""
    render = scene.render
    if PROP_WIDTH in obj and PROP_HEIGHT in obj:
        width, height = int(obj[PROP_WIDTH]), int(obj[PROP_HEIGHT])
    else:
        scale = render.resolution_percentage / 100.0
        width = max(1, int(render.resolution_x * scale))
        height = max(1, int(render.resolution_y * scale))
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
    fx, fy, cx, cy = intrinsics_from_blender(data.lens, data.sensor_width, data.sensor_height, data.sensor_fit,
                                             data.shift_x, data.shift_y, width, height, ax, ay)
    R, t = pose_from_blender_matrix(obj.matrix_world)
    cam = Camera(R=R, t=t, fx=fx, fy=fy, cx=cx, cy=cy, width=width, height=height,
                 name=name if name is not None else obj.name,
                 near=float(data.clip_start), far=float(data.clip_end))
    return cam.validate(f"Blender camera {obj.name!r}")


def apply_camera_to_object(cam: Camera, obj, scene=None, set_scene_frame: bool = False) -> None:
    """Set a Blender camera object's pose and lens so it sees exactly what `cam` sees."""
    settings = blender_from_intrinsics(cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height)
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
    obj.matrix_world = _to_blender_matrix(blender_matrix_from_pose(cam.R, cam.t))
    if set_scene_frame and scene is not None:
        render = scene.render
        render.resolution_x = settings["resolution_x"]
        render.resolution_y = settings["resolution_y"]
        render.resolution_percentage = 100
        render.pixel_aspect_x = settings["pixel_aspect_x"]
        render.pixel_aspect_y = settings["pixel_aspect_y"]


def new_camera_object(cam: Camera, collection, scene=None, name: str | None = None):
    """Create a camera object for `cam` in `collection` and return it."""
    import bpy  # only the adapters touch bpy; the maths above runs anywhere

    label = name or cam.name or "gsgs_camera"
    data = bpy.data.cameras.new(label)
    obj = bpy.data.objects.new(label, data)
    collection.objects.link(obj)
    apply_camera_to_object(cam, obj, scene)
    # Frustum drawing size in the viewport, relative to nothing the user set yet.
    data.display_size = 0.25
    return obj


def _to_blender_matrix(m: np.ndarray):
    from mathutils import Matrix

    return Matrix([[float(v) for v in row] for row in m])


def fov_degrees(cam: Camera) -> tuple[float, float]:
    return math.degrees(cam.fov_x), math.degrees(cam.fov_y)
