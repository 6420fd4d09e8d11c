"""One camera type for the whole project, in the OpenCV / COLMAP convention.

Internally a camera is a world-to-camera rotation R and translation t (x right, y down,
z forward) plus pinhole intrinsics. Pixel coordinates are continuous with the centre of
the top-left pixel at (0.5, 0.5) (COLMAP's and gsplat's convention): a principal point in
the middle of a W x H image is (W / 2, H / 2). Every other convention (Blender, NeRF /
OpenGL, LLFF, COLMAP) converts through the functions in this module. numpy only: the
Blender add-on imports this file.
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
