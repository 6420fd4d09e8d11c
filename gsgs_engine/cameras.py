"""One camera type for the whole project, in the OpenCV / COLMAP convention.

Internally a camera is a world-to-camera rotation R and translation t (x right, y down,
z forward) plus pinhole intrinsics. Pixel coordinates are continuous with the centre of
the top-left pixel at (0.5, 0.5) (COLMAP's and gsplat's convention): a principal point in
the middle of a W x H image is (W / 2, H / 2). Every other convention (Blender, NeRF /
OpenGL, LLFF, COLMAP) converts through the functions in this module. numpy only: the
Blender add-on imports this file.

Lens distortion (COLMAP SIMPLE_RADIAL / RADIAL / OPENCV / FULL_OPENCV, NeRF k1..p2) is not
carried into training: such a photo gets a pinhole Camera plus an `Undistortion` (remap tables)
that the loader applies when it decodes the image. Other models are refused with the fix.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from gsgs_engine import GsgsError


@dataclass(frozen=True)
class Camera:
    R: np.ndarray  # (3, 3) world -> camera rotation
    t: np.ndarray  # (3,) world -> camera translation: x_cam = R @ x_world + t
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    name: str = ""
    time: float | None = None  # normalised [0, 1] for dynamic scenes, None for static
    near: float | None = None
    far: float | None = None
    extra: dict = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        R = np.asarray(self.R, dtype=np.float64).reshape(3, 3)
        t = np.asarray(self.t, dtype=np.float64).reshape(3)
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        for name in ("fx", "fy", "cx", "cy"):
            object.__setattr__(self, name, float(getattr(self, name)))

    # -- validation -------------------------------------------------------------------
    def validate(self, source: str = "camera") -> "Camera":
        """Raise GsgsError naming `source` if the pose or intrinsics are unusable."""
        label = f"{source}" + (f" ({self.name})" if self.name else "")
        if not (np.all(np.isfinite(self.R)) and np.all(np.isfinite(self.t))):
            raise GsgsError(f"{label}: the camera pose contains NaN or Inf; fix or remove this view")
        if abs(np.linalg.det(self.R) - 1.0) > 1e-3 or not np.allclose(self.R @ self.R.T, np.eye(3), atol=1e-3):
            raise GsgsError(f"{label}: the camera rotation is not a proper rotation (det {np.linalg.det(self.R):.4f}); check the pose matrix")
        intr = np.array([self.fx, self.fy, self.cx, self.cy])
        if not np.all(np.isfinite(intr)) or self.fx <= 0 or self.fy <= 0:
            raise GsgsError(f"{label}: focal length must be finite and positive (fx={self.fx}, fy={self.fy})")
        if self.width <= 0 or self.height <= 0:
            raise GsgsError(f"{label}: image size must be positive (got {self.width}x{self.height})")
        return self

    # -- matrices ---------------------------------------------------------------------
    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def world_to_camera(self) -> np.ndarray:
        m = np.eye(4)
        m[:3, :3] = self.R
        m[:3, 3] = self.t
        return m

    @property
    def camera_to_world(self) -> np.ndarray:
        m = np.eye(4)
        m[:3, :3] = self.R.T
        m[:3, 3] = -self.R.T @ self.t
        return m

    @property
    def center(self) -> np.ndarray:
        return -self.R.T @ self.t

    @property
    def fov_x(self) -> float:
        return 2.0 * np.arctan(self.width / (2.0 * self.fx))

    @property
    def fov_y(self) -> float:
        return 2.0 * np.arctan(self.height / (2.0 * self.fy))

    # -- geometry ---------------------------------------------------------------------
    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """World points (N, 3) -> camera-frame points (N, 3)."""
        return np.asarray(points, dtype=np.float64) @ self.R.T + self.t

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (N, 3) -> (pixel coordinates (N, 2), depth along +z (N,))."""
        pc = self.to_camera(points)
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.fx * pc[:, 0] / z + self.cx
            v = self.fy * pc[:, 1] / z + self.cy
        return np.stack([u, v], axis=-1), z

    def pixel_rays(self) -> tuple[np.ndarray, np.ndarray]:
        """Ray origins and unit directions (H, W, 3) through every pixel centre, in world space."""
        j, i = np.meshgrid(np.arange(self.height) + 0.5, np.arange(self.width) + 0.5, indexing="ij")
        d_cam = np.stack([(i - self.cx) / self.fx, (j - self.cy) / self.fy, np.ones_like(i)], axis=-1)
        d_world = d_cam @ self.R  # R^T applied to row vectors
        d_world /= np.linalg.norm(d_world, axis=-1, keepdims=True)
        origin = np.broadcast_to(self.center, d_world.shape)
        return origin, d_world

    def scaled(self, factor: float) -> "Camera":
        """The same camera for an image resized by `factor` (e.g. 0.5 halves both sides)."""
        w = max(1, int(round(self.width * factor)))
        h = max(1, int(round(self.height * factor)))
        sx, sy = w / self.width, h / self.height
        return replace(self, fx=self.fx * sx, fy=self.fy * sy, cx=self.cx * sx, cy=self.cy * sy, width=w, height=h)

    def cropped_rows(self, y0: int, y1: int) -> "Camera":
        """The same camera seeing only its rows [y0, y1): pose and focal lengths kept, the principal point moved."""
        if not 0 <= y0 < y1 <= self.height:
            raise ValueError(f"rows [{y0}, {y1}) are not inside the {self.height} rows of camera {self.name!r}")
        return replace(self, cy=self.cy - y0, height=y1 - y0, name=f"{self.name}[rows {y0}:{y1}]")

    def with_pose(self, R: np.ndarray, t: np.ndarray, name: str | None = None) -> "Camera":
        return replace(self, R=np.asarray(R, dtype=np.float64), t=np.asarray(t, dtype=np.float64),
                       name=self.name if name is None else name)

    def to_dict(self) -> dict:
        """JSON-ready description (the job folder stores cameras this way)."""
        d = {"R": self.R.tolist(), "t": self.t.tolist(), "fx": self.fx, "fy": self.fy, "cx": self.cx,
             "cy": self.cy, "width": self.width, "height": self.height, "name": self.name}
        if self.time is not None:
            d["time"] = self.time
        if self.near is not None:
            d["near"] = self.near
        if self.far is not None:
            d["far"] = self.far
        return d

    @classmethod
    def from_dict(cls, d: dict, source: str = "camera") -> "Camera":
        try:
            cam = cls(R=np.array(d["R"], dtype=np.float64), t=np.array(d["t"], dtype=np.float64),
                      fx=d["fx"], fy=d["fy"], cx=d["cx"], cy=d["cy"], width=d["width"], height=d["height"],
                      name=d.get("name", ""), time=d.get("time"), near=d.get("near"), far=d.get("far"))
        except (KeyError, TypeError, ValueError) as exc:
            raise GsgsError(f"{source}: malformed camera entry ({exc}); expected R, t, fx, fy, cx, cy, width, height") from exc
        return cam.validate(source)


# -- rotations ------------------------------------------------------------------------------
def quat_to_rotmat(q: np.ndarray) -> np.ndarray:
    """Quaternion(s) (..., 4) as (w, x, y, z), any norm -> rotation matrices (..., 3, 3)."""
    q = np.asarray(q, dtype=np.float64)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(norm == 0) or not np.all(np.isfinite(q)):
        raise GsgsError("quaternion is zero or not finite; a rotation needs a non-zero finite (w, x, y, z)")
    w, x, y, z = np.moveaxis(q / norm, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def rotmat_to_quat(R: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> unit quaternions (..., 4) (w, x, y, z) with w >= 0."""
    R = np.asarray(R, dtype=np.float64)
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    # Four algebraically equal forms; use the one with the largest (best-conditioned) divisor.
    cands = np.stack([
        np.stack([1 + m00 + m11 + m22, R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1),
        np.stack([R[..., 2, 1] - R[..., 1, 2], 1 + m00 - m11 - m22, R[..., 0, 1] + R[..., 1, 0], R[..., 0, 2] + R[..., 2, 0]], -1),
        np.stack([R[..., 0, 2] - R[..., 2, 0], R[..., 0, 1] + R[..., 1, 0], 1 - m00 + m11 - m22, R[..., 1, 2] + R[..., 2, 1]], -1),
        np.stack([R[..., 1, 0] - R[..., 0, 1], R[..., 0, 2] + R[..., 2, 0], R[..., 1, 2] + R[..., 2, 1], 1 - m00 - m11 + m22], -1),
    ], -2)  # (..., 4 candidates, 4); candidate k has 4 * q_k^2 in slot k
    diag = np.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1)
    best = np.argmax(diag, axis=-1)
    q = np.take_along_axis(cands, best[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def slerp(q0: np.ndarray, q1: np.ndarray, t) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions (w, x, y, z) along the shorter arc.

    `t` may be a scalar or an array; the result has shape t.shape + (4,) for a 1-D pair.
    """
    q0 = np.asarray(q0, dtype=np.float64)
    q1 = np.asarray(q1, dtype=np.float64)
    q0 = q0 / np.linalg.norm(q0, axis=-1, keepdims=True)
    q1 = q1 / np.linalg.norm(q1, axis=-1, keepdims=True)
    t = np.asarray(t, dtype=np.float64)[..., None]
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)  # q and -q are the same rotation; take the short way
    dot = np.clip(np.abs(dot), -1.0, 1.0)
    theta = np.arccos(dot)
    sin_theta = np.sin(theta)
    near = sin_theta < 1e-6  # nearly identical: lerp is exact to first order and avoids 0/0
    safe = np.where(near, 1.0, sin_theta)
    w0 = np.where(near, 1.0 - t, np.sin((1.0 - t) * theta) / safe)
    w1 = np.where(near, t, np.sin(t * theta) / safe)
    q = w0 * q0 + w1 * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def interpolate_cameras(a: Camera, b: Camera, t: float, name: str = "") -> Camera:
    """Camera between `a` (t=0) and `b` (t=1): slerped orientation, linear centre and intrinsics."""
    qa = rotmat_to_quat(a.R.T)  # camera-to-world orientations
    qb = rotmat_to_quat(b.R.T)
    c2w_rot = quat_to_rotmat(slerp(qa, qb, t))
    center = (1.0 - t) * a.center + t * b.center
    R = c2w_rot.T
    lerp = lambda x, y: (1.0 - t) * x + t * y  # noqa: E731
    return replace(a, R=R, t=-R @ center, fx=lerp(a.fx, b.fx), fy=lerp(a.fy, b.fy), cx=lerp(a.cx, b.cx),
                   cy=lerp(a.cy, b.cy), name=name or f"{a.name}~{b.name}@{t:.3f}")


def interpolate_cameras_around(a: Camera, b: Camera, t: float, focus, name: str = "") -> Camera:
    """interpolate_cameras, but the centre travels on the arc around `focus`: its direction from the
    focus is slerped and its distance lerped. For cameras orbiting an object, a straight line between
    two views 90 degrees apart passes at 0.71 of their distance, often inside the object's bounds.
    """
    cam = interpolate_cameras(a, b, t, name)
    focus = np.asarray(focus, dtype=np.float64).reshape(3)
    ra, rb = a.center - focus, b.center - focus
    na, nb = float(np.linalg.norm(ra)), float(np.linalg.norm(rb))
    if na < 1e-9 or nb < 1e-9:
        return cam
    direction = slerp_directions(ra / na, rb / nb, t)
    if direction is None:  # opposite sides of the focus: no unique arc, keep the straight line
        return cam
    center = focus + ((1.0 - t) * na + t * nb) * direction
    # the slerped orientation misses the focus by a few degrees off the arc's plane: re-aim the
    # optical axis at it with the smallest rotation (keeps the roll of the slerp)
    R = cam.R @ rotation_between(cam.R[2], -direction).T
    return replace(cam, R=R, t=-R @ center)


def rotation_between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The smallest rotation taking direction `u` to direction `v` (Rodrigues); identity when parallel,
    a half turn about a perpendicular axis when opposite."""
    u = np.asarray(u, dtype=np.float64) / np.linalg.norm(u)
    v = np.asarray(v, dtype=np.float64) / np.linalg.norm(v)
    axis = np.cross(u, v)
    s, c = float(np.linalg.norm(axis)), float(u @ v)
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        perp = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
        perp /= np.linalg.norm(perp)
        return 2.0 * np.outer(perp, perp) - np.eye(3)
    k = axis / s
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def slerp_directions(u: np.ndarray, v: np.ndarray, t: float) -> np.ndarray | None:
    """Great-circle interpolation of unit vectors; None when they are (nearly) opposite."""
    cos = float(np.clip(u @ v, -1.0, 1.0))
    if cos < -1.0 + 1e-6:
        return None
    angle = np.arccos(cos)
    if angle < 1e-6:
        return u.copy()
    return (np.sin((1.0 - t) * angle) * u + np.sin(t * angle) * v) / np.sin(angle)


def optical_axes_system(cameras) -> tuple[np.ndarray, np.ndarray]:
    """Normal equations (A, b) of the point nearest to every optical axis: sum_i (I - d_i d_i^T)(x - c_i) = 0.

    Solve A x = b when the axes cross at a real angle (A well conditioned); the smallest
    eigenvalue of A says how well (0 for parallel axes).
    """
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for cam in cameras:
        d = cam.R[2]  # optical axis (camera +z) in world coordinates
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ cam.center
    return A, b


def focus_point(cameras) -> tuple[np.ndarray, str]:
    """The point the cameras look at: least-squares nearest point to all optical axes.

    Forward-facing rigs (near-parallel axes) have no such point; there the focus is the mean
    centre pushed along the mean axis to the scene's typical depth (geometric mean of near/far).
    """
    centers = np.stack([c.center for c in cameras])
    dirs = np.stack([c.R[2] for c in cameras])  # optical axis (camera +z) in world coordinates
    A, b = optical_axes_system(cameras)
    eig = np.linalg.eigvalsh(A)
    if len(cameras) >= 2 and eig[0] > 0.05 * len(cameras):  # axes cross at a real angle
        return np.linalg.solve(A, b), "optical axes intersection"
    near = getattr(cameras[0], "near", None)
    far = getattr(cameras[0], "far", None)
    depth = float(np.sqrt(near * far)) if near and far else 1.0
    axis = dirs.mean(0)
    axis /= max(np.linalg.norm(axis), 1e-12)
    return centers.mean(0) + depth * axis, "forward-facing: mean axis at the scene depth"


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera (R, t) of an OpenCV camera at `eye` looking at `target`, `up` pointing up in the image."""
    eye = np.asarray(eye, dtype=np.float64)
    forward = np.asarray(target, dtype=np.float64) - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, np.asarray(up, dtype=np.float64))
    if np.linalg.norm(right) < 1e-9:
        raise GsgsError("look_at: the viewing direction is parallel to `up`; pass another up vector")
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    R = np.stack([right, down, forward])  # rows: camera axes expressed in world coordinates
    return R, -R @ eye


def _rotation_from_c2w(m: np.ndarray, source: str) -> tuple[np.ndarray, np.ndarray]:
    """(rotation, position) of a camera-to-world 4x4 or 3x4 matrix, scale removed (Blender does the same)."""
    m = np.asarray(m, dtype=np.float64)
    if m.shape not in ((4, 4), (3, 4)):
        raise GsgsError(f"{source}: camera matrix has shape {m.shape}; expected 4x4 (or 3x4) camera-to-world")
    if not np.all(np.isfinite(m)):
        raise GsgsError(f"{source}: the camera pose contains NaN or Inf; fix or remove this view")
    rot = m[:3, :3]
    norms = np.linalg.norm(rot, axis=0)
    if np.any(norms < 1e-12) or np.linalg.det(rot) <= 0:
        raise GsgsError(f"{source}: the camera matrix is degenerate or mirrored (det {np.linalg.det(rot):.4g}); "
                        "use a proper rotation without negative scale")
    unit = rot / norms
    skew = float(np.abs(unit.T @ unit - np.eye(3)).max())
    if skew > 1e-3:  # the tolerance Camera.validate gives an inline rotation: float32 rounding, not shear
        raise GsgsError(f"{source}: the camera matrix is sheared (its axes are {np.degrees(np.arcsin(min(skew, 1))):.1f} "
                        "degrees from perpendicular); a camera-to-world matrix needs perpendicular axes (scale is "
                        "removed, shear cannot be): re-export the poses")
    u, _, vt = np.linalg.svd(unit)  # nearest rotation: files store float32, slightly non-orthogonal
    return u @ vt, m[:3, 3].copy()


# OpenCV camera axes (x right, y down, z forward) vs Blender / OpenGL ones (x right, y up, z back).
_FLIP_YZ = np.diag([1.0, -1.0, -1.0])


def _opengl_c2w_to_camera_pose(c2w: np.ndarray, source: str) -> tuple[np.ndarray, np.ndarray]:
    rot_gl, position = _rotation_from_c2w(c2w, source)
    R = (rot_gl @ _FLIP_YZ).T  # world -> OpenCV camera
    return R, -R @ position


def _camera_pose_to_opengl_c2w(camera: Camera) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = camera.R.T @ _FLIP_YZ
    m[:3, 3] = camera.center
    return m


# -- Blender ------------------------------------------------------------------------------
SENSOR_FITS = ("AUTO", "HORIZONTAL", "VERTICAL")


def _blender_fit(sensor_fit: str, width: int, height: int, aspect_x: float, aspect_y: float,
                 sensor_width: float, sensor_height: float) -> tuple[str, float, float]:
    """(resolved fit, sensor size in mm along it, that size in pixels), as Blender's
    BKE_camera_params_compute_viewplane: AUTO fits the larger of width*aspect_x vs height*aspect_y
    but always uses sensor_width; HORIZONTAL uses sensor_width, VERTICAL sensor_height."""
    if sensor_fit not in SENSOR_FITS:
        raise GsgsError(f"unknown Blender sensor_fit {sensor_fit!r}; expected one of {', '.join(SENSOR_FITS)}")
    fit = sensor_fit
    if fit == "AUTO":
        fit = "HORIZONTAL" if width * aspect_x >= height * aspect_y else "VERTICAL"
    sensor = sensor_height if sensor_fit == "VERTICAL" else sensor_width
    ycor = aspect_y / aspect_x
    view_pixels = width if fit == "HORIZONTAL" else ycor * height
    return fit, sensor, view_pixels


def camera_from_blender(matrix_world, lens: float, sensor_width: float = 36.0, sensor_height: float = 24.0,
                        sensor_fit: str = "AUTO", shift_x: float = 0.0, shift_y: float = 0.0,
                        resolution_x: int = 1920, resolution_y: int = 1080, resolution_percentage: int = 100,
                        pixel_aspect_x: float = 1.0, pixel_aspect_y: float = 1.0,
                        clip_start: float | None = None, clip_end: float | None = None, name: str = "") -> Camera:
    """A Blender perspective camera (plain numbers: obj.matrix_world, cam.lens, ...) -> Camera.

    Blender looks down -Z with +Y up; object scale is ignored, as Blender's renderer does.
    shift_x / shift_y are fractions of the sensor-fitted image size, so the principal point moves
    by shift * that size in pixels (y flips: +shift_y moves the image content down).
    """
    source = f"Blender camera {name!r}" if name else "Blender camera"
    if lens <= 0 or sensor_width <= 0 or sensor_height <= 0 or pixel_aspect_x <= 0 or pixel_aspect_y <= 0:
        raise GsgsError(f"{source}: lens, sensor size and pixel aspect must be positive")
    # Blender's BKE_render_resolution truncates the percentage-scaled size.
    width = int(resolution_x) * int(resolution_percentage) // 100
    height = int(resolution_y) * int(resolution_percentage) // 100
    _, sensor, view_pixels = _blender_fit(sensor_fit, width, height, pixel_aspect_x, pixel_aspect_y,
                                          sensor_width, sensor_height)
    ycor = pixel_aspect_y / pixel_aspect_x
    fx = lens * view_pixels / sensor
    fy = fx / ycor  # a pixel is ycor times as tall as wide: fewer rows per unit of height
    cx = 0.5 * width - shift_x * view_pixels
    cy = 0.5 * height + shift_y * view_pixels / ycor
    R, t = _opengl_c2w_to_camera_pose(np.asarray(matrix_world, dtype=np.float64), source)
    return Camera(R=R, t=t, fx=fx, fy=fy, cx=cx, cy=cy, width=width, height=height, name=name,
                  near=clip_start, far=clip_end).validate(source)


def blender_from_camera(camera: Camera, sensor_width: float = 36.0, sensor_height: float = 24.0,
                        sensor_fit: str = "AUTO") -> dict:
    """Camera -> the plain numbers to set on a Blender camera object and scene.

    Returns the keyword arguments of camera_from_blender (matrix_world 4x4 list, lens, sensor_*,
    shift_x/y, resolution_x/y, resolution_percentage=100, pixel_aspect_x/y), so
    camera_from_blender(**blender_from_camera(cam)) reproduces cam. Non-square pixels (fx != fy)
    become a pixel aspect >= 1 on one axis, as Blender requires.
    """
    ycor = camera.fx / camera.fy
    aspect_x, aspect_y = (1.0, ycor) if ycor >= 1.0 else (1.0 / ycor, 1.0)
    _, sensor, view_pixels = _blender_fit(sensor_fit, camera.width, camera.height, aspect_x, aspect_y,
                                          sensor_width, sensor_height)
    d = {
        "matrix_world": _camera_pose_to_opengl_c2w(camera).tolist(),
        "lens": camera.fx * sensor / view_pixels,
        "sensor_width": float(sensor_width),
        "sensor_height": float(sensor_height),
        "sensor_fit": sensor_fit,
        "shift_x": (0.5 * camera.width - camera.cx) / view_pixels,
        "shift_y": (camera.cy - 0.5 * camera.height) * ycor / view_pixels,
        "resolution_x": camera.width,
        "resolution_y": camera.height,
        "resolution_percentage": 100,
        "pixel_aspect_x": aspect_x,
        "pixel_aspect_y": aspect_y,
        "name": camera.name,
    }
    if camera.near is not None:
        d["clip_start"] = camera.near
    if camera.far is not None:
        d["clip_end"] = camera.far
    return d


# -- NeRF transforms.json -------------------------------------------------------------------
def nerf_intrinsics(width: int, height: int, camera_angle_x: float | None = None,
                    camera_angle_y: float | None = None, fl_x: float | None = None, fl_y: float | None = None,
                    cx: float | None = None, cy: float | None = None, source: str = "transforms.json"
                    ) -> tuple[float, float, float, float]:
    """(fx, fy, cx, cy) from NeRF / instant-ngp keys: fl_x/fl_y win over camera_angle_x/y;
    a missing vertical value means square pixels; a missing cx/cy means the image centre."""
    if fl_x is not None:
        fx = float(fl_x)
    elif camera_angle_x is not None:
        fx = 0.5 * width / np.tan(0.5 * float(camera_angle_x))
    elif fl_y is not None or camera_angle_y is not None:
        fx = None
    else:
        raise GsgsError(f"{source}: no focal length; add camera_angle_x (radians) or fl_x (pixels)")
    if fl_y is not None:
        fy = float(fl_y)
    elif camera_angle_y is not None:
        fy = 0.5 * height / np.tan(0.5 * float(camera_angle_y))
    else:
        fy = fx
    fx = fy if fx is None else fx
    cx = 0.5 * width if cx is None else float(cx)
    cy = 0.5 * height if cy is None else float(cy)
    if not (np.isfinite([fx, fy, cx, cy]).all() and fx > 0 and fy > 0):
        raise GsgsError(f"{source}: focal length must be finite and positive (fx={fx}, fy={fy}); check camera_angle_x / fl_x")
    return fx, fy, cx, cy


def camera_from_nerf(c2w, width: int, height: int, camera_angle_x: float | None = None,
                     camera_angle_y: float | None = None, fl_x: float | None = None, fl_y: float | None = None,
                     cx: float | None = None, cy: float | None = None, name: str = "",
                     near: float | None = None, far: float | None = None, source: str = "transforms.json") -> Camera:
    """A NeRF frame (OpenGL camera-to-world: x right, y up, z back) + intrinsics -> Camera."""
    fx, fy, cx, cy = nerf_intrinsics(width, height, camera_angle_x, camera_angle_y, fl_x, fl_y, cx, cy, source)
    R, t = _opengl_c2w_to_camera_pose(c2w, source)
    return Camera(R=R, t=t, fx=fx, fy=fy, cx=cx, cy=cy, width=width, height=height, name=name,
                  near=near, far=far).validate(source)


def nerf_c2w_from_camera(camera: Camera) -> np.ndarray:
    """Camera -> NeRF transform_matrix (4x4 OpenGL camera-to-world)."""
    return _camera_pose_to_opengl_c2w(camera)


# -- LLFF poses_bounds.npy ----------------------------------------------------------------
def cameras_from_llff(array, image_size: tuple[int, int], names: list[str] | None = None,
                      source: str = "poses_bounds.npy") -> list[Camera]:
    """LLFF rows (N, 17) -> cameras for images of `image_size` = (width, height).

    Each row is a 3x5 matrix [c2w rotation columns (down, right, back) | position | (h, w, f)]
    followed by the near and far bounds. h, w, f describe the full-resolution photos; the
    intrinsics are rescaled to the actual images, with the principal point at the centre.
    """
    a = np.asarray(array, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 17:
        raise GsgsError(f"{source}: expected an (N, 17) array of LLFF poses and bounds, got shape {a.shape}")
    width, height = int(image_size[0]), int(image_size[1])
    cams = []
    for i, row in enumerate(a):
        label = f"{source} row {i}" + (f" ({names[i]})" if names else "")
        if not np.all(np.isfinite(row)):
            raise GsgsError(f"{label}: the camera pose contains NaN or Inf; fix or remove this view")
        m = row[:15].reshape(3, 5)
        h, w, f = m[:, 4]
        if h <= 0 or w <= 0 or f <= 0:
            raise GsgsError(f"{label}: image size and focal (h={h}, w={w}, f={f}) must be positive")
        if abs(width / w - height / h) > 0.01 * (width / w):
            raise GsgsError(f"{label}: images are {width}x{height} but the poses describe {w:.0f}x{h:.0f} "
                            "photos (a different aspect ratio); use the images these poses were computed for")
        down, right, back = m[:, 0], m[:, 1], m[:, 2]
        c2w = np.eye(4)
        c2w[:3, :3] = np.stack([right, down, -back], axis=1)  # OpenCV camera axes in world coordinates
        c2w[:3, 3] = m[:, 3]
        rot, position = _rotation_from_c2w(c2w, label)
        R = rot.T
        sx, sy = width / w, height / h
        near, far = float(row[15]), float(row[16])
        cams.append(Camera(R=R, t=-R @ position, fx=f * sx, fy=f * sy, cx=0.5 * width, cy=0.5 * height,
                           width=width, height=height, name=names[i] if names else f"{i:03d}",
                           near=near, far=far).validate(label))
    return cams


def llff_from_cameras(cameras: list[Camera], near: float | None = None, far: float | None = None) -> np.ndarray:
    """Cameras -> LLFF (N, 17) rows (centred principal point assumed; fx is stored as f)."""
    rows = []
    for cam in cameras:
        c2w = cam.camera_to_world
        right, down, fwd = c2w[:3, 0], c2w[:3, 1], c2w[:3, 2]
        m = np.stack([down, right, -fwd, c2w[:3, 3], [cam.height, cam.width, cam.fx]], axis=1)
        n = cam.near if near is None else near
        f = cam.far if far is None else far
        rows.append(np.concatenate([m.reshape(-1), [n if n is not None else 0.0, f if f is not None else 0.0]]))
    return np.stack(rows)


# -- COLMAP -------------------------------------------------------------------------------------
# Parameter layouts, as in COLMAP's src/colmap/sensor/models.h.
COLMAP_MODELS: dict[str, tuple[str, ...]] = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
    "FULL_OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
}


def _colmap_params(model: str, params, source: str) -> tuple[float, float, float, float, dict]:
    """(fx, fy, cx, cy, distortion coefficients) of a COLMAP camera."""
    if model not in COLMAP_MODELS:
        raise GsgsError(f"{source}: COLMAP camera model {model} is not supported (supported: "
                        f"{', '.join(COLMAP_MODELS)}); undistort first with `colmap image_undistorter` "
                        "(or pycolmap.undistort_images) and load the undistorted folder")
    names = COLMAP_MODELS[model]
    params = [float(p) for p in params]
    if len(params) != len(names):
        raise GsgsError(f"{source}: COLMAP model {model} takes {len(names)} parameters, got {len(params)}")
    p = dict(zip(names, params))
    if not np.all(np.isfinite(params)):
        raise GsgsError(f"{source}: camera parameters contain NaN or Inf; re-run the reconstruction")
    fx = p.pop("f") if "f" in p else p.pop("fx")
    fy = p.pop("fy", fx)
    cx, cy = p.pop("cx"), p.pop("cy")
    if "k" in p:
        p["k1"] = p.pop("k")
    return fx, fy, cx, cy, p


def distort_normalized(x: np.ndarray, y: np.ndarray, coeffs: dict) -> tuple[np.ndarray, np.ndarray]:
    """Apply COLMAP / OpenCV radial-tangential distortion to normalized image coordinates."""
    k1, k2, k3 = coeffs.get("k1", 0.0), coeffs.get("k2", 0.0), coeffs.get("k3", 0.0)
    k4, k5, k6 = coeffs.get("k4", 0.0), coeffs.get("k5", 0.0), coeffs.get("k6", 0.0)
    p1, p2 = coeffs.get("p1", 0.0), coeffs.get("p2", 0.0)
    r2 = x * x + y * y
    radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + 2 * p2 * x * y + p1 * (r2 + 2 * y * y)
    return xd, yd


def undistort_normalized(xd: np.ndarray, yd: np.ndarray, coeffs: dict, iterations: int = 100
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Invert distort_normalized by Newton's method with a numeric Jacobian (as COLMAP does)."""
    x, y = np.array(xd, dtype=np.float64), np.array(yd, dtype=np.float64)
    eps = 1e-9
    for _ in range(iterations):
        fx_, fy_ = distort_normalized(x, y, coeffs)
        ex, ey = fx_ - xd, fy_ - yd
        if max(np.abs(ex).max(initial=0), np.abs(ey).max(initial=0)) < 1e-12:
            break
        ax, ay = distort_normalized(x + eps, y, coeffs)
        bx, by = distort_normalized(x, y + eps, coeffs)
        j00, j10 = (ax - fx_) / eps, (ay - fy_) / eps
        j01, j11 = (bx - fx_) / eps, (by - fy_) / eps
        det = j00 * j11 - j01 * j10
        det = np.where(np.abs(det) < 1e-12, 1e-12, det)
        x = x - (j11 * ex - j01 * ey) / det
        y = y - (-j10 * ex + j00 * ey) / det
    return x, y


@dataclass(frozen=True)
class Undistortion:
    """How to resample a distorted photo into the pinhole `target` camera.

    `source` holds the distorted camera's pinhole part; `coeffs` its distortion. maps() gives
    cv2.remap maps (float32, OpenCV's integer pixel centres) the size of the target image.
    """

    source: Camera
    target: Camera
    coeffs: dict

    def maps(self) -> tuple[np.ndarray, np.ndarray]:
        t, s = self.target, self.source
        v, u = np.meshgrid(np.arange(t.height) + 0.5, np.arange(t.width) + 0.5, indexing="ij")
        xd, yd = distort_normalized((u - t.cx) / t.fx, (v - t.cy) / t.fy, self.coeffs)
        # continuous coordinates (top-left centre 0.5) -> OpenCV's (top-left centre 0)
        return (s.fx * xd + s.cx - 0.5).astype(np.float32), (s.fy * yd + s.cy - 0.5).astype(np.float32)

    def scaled(self, factor: float) -> "Undistortion":
        return Undistortion(self.source.scaled(factor), self.target.scaled(factor), self.coeffs)


def _undistorted_pinhole(distorted: Camera, coeffs: dict) -> Camera:
    """Pinhole intrinsics (same size and aspect of focal lengths) whose every pixel sees inside
    the distorted photo: no blank border, like COLMAP's undistorter with blank_pixels=0."""
    w, h = distorted.width, distorted.height
    s = np.linspace(0.0, 1.0, 257)

    def border(u, v):
        return undistort_normalized((u - distorted.cx) / distorted.fx, (v - distorted.cy) / distorted.fy, coeffs)

    left_x, _ = border(np.zeros_like(s), s * h)
    right_x, _ = border(np.full_like(s, w), s * h)
    _, top_y = border(s * w, np.zeros_like(s))
    _, bottom_y = border(s * w, np.full_like(s, h))
    x0, x1, y0, y1 = left_x.max(), right_x.min(), top_y.max(), bottom_y.min()
    if not (x1 > x0 and y1 > y0):
        raise GsgsError(f"camera {distorted.name!r}: distortion {coeffs} folds the image; "
                        "undistort with `colmap image_undistorter` instead")
    scale = max(w / ((x1 - x0) * distorted.fx), h / ((y1 - y0) * distorted.fy))
    fx, fy = distorted.fx * scale, distorted.fy * scale
    return replace(distorted, fx=fx, fy=fy, cx=0.5 * w - fx * 0.5 * (x0 + x1), cy=0.5 * h - fy * 0.5 * (y0 + y1))


def undistortion_for(distorted: Camera, coeffs: dict) -> tuple[Camera, Undistortion | None]:
    """(pinhole camera to train with, Undistortion or None) for a camera with distortion `coeffs`
    (k1..k6, p1, p2 as in OpenCV; zeros or an empty dict mean a pinhole camera already)."""
    coeffs = {k: float(v) for k, v in coeffs.items() if v}
    if not coeffs:
        return distorted, None
    target = _undistorted_pinhole(distorted, coeffs)
    return target, Undistortion(source=distorted, target=target, coeffs=coeffs)


def camera_from_colmap(qvec, tvec, model: str, params, width: int, height: int, name: str = "",
                       source: str = "COLMAP model") -> tuple[Camera, Undistortion | None]:
    """COLMAP image pose (qvec w,x,y,z and tvec, world -> camera) + camera -> (Camera, undistortion).

    Pinhole models convert directly (undistortion None). Distorted models (SIMPLE_RADIAL, RADIAL,
    OPENCV, FULL_OPENCV) give the pinhole Camera the photo must be resampled into plus the
    Undistortion the loader applies; any other model is refused with the fix to run.
    COLMAP's pixel convention (top-left centre at 0.5) is ours, so cx, cy carry over unchanged.
    """
    label = f"{source} ({name})" if name else source
    q = np.asarray(qvec, dtype=np.float64)
    tv = np.asarray(tvec, dtype=np.float64)
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(tv))):
        raise GsgsError(f"{label}: the camera pose contains NaN or Inf; fix or remove this view")
    fx, fy, cx, cy, coeffs = _colmap_params(model, params, label)
    cam = Camera(R=quat_to_rotmat(q), t=tv, fx=fx, fy=fy, cx=cx, cy=cy, width=width, height=height,
                 name=name).validate(label)
    return undistortion_for(cam, coeffs)


def colmap_from_camera(camera: Camera) -> tuple[np.ndarray, np.ndarray, str, list[float]]:
    """Camera -> (qvec w,x,y,z, tvec, "PINHOLE", [fx, fy, cx, cy]) as COLMAP stores an image + camera."""
    return rotmat_to_quat(camera.R), camera.t.copy(), "PINHOLE", [camera.fx, camera.fy, camera.cx, camera.cy]
