"""The Scene type every loader returns and every consumer (trainer, prior, add-on) reads.

Images load lazily: a View keeps a path (or a callable) and decodes on request, so a
100-view, 800 px scene costs memory only for the views in use.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera


@dataclass
class View:
    """One posed image. `load_rgba()` returns float32 (H, W, 3 or 4) in [0, 1]."""

    camera: Camera
    image_path: Path | None
    loader: Callable[[], np.ndarray] | None = None
    background: np.ndarray = field(default_factory=lambda: np.ones(3, dtype=np.float32))

    @property
    def name(self) -> str:
        return self.camera.name

    @property
    def time(self) -> float | None:
        return self.camera.time

    def load_rgba(self) -> np.ndarray:
        if self.loader is None:
            raise GsgsError(f"view {self.name!r} has no image")
        img = self.loader()
        h, w = img.shape[:2]
        if (w, h) != (self.camera.width, self.camera.height):
            raise GsgsError(
                f"{self.image_path}: image is {w}x{h} but its camera expects "
                f"{self.camera.width}x{self.camera.height}; resize the image or fix the intrinsics")
        return img

    def image(self) -> np.ndarray:
        """RGB float32 (H, W, 3); RGBA images are composited on the scene background."""
        img = self.load_rgba()
        if img.shape[2] == 4:
            a = img[..., 3:4]
            return (img[..., :3] * a + self.background[None, None, :] * (1.0 - a)).astype(np.float32)
        return img[..., :3]

    def alpha(self) -> np.ndarray | None:
        img = self.load_rgba()
        return img[..., 3] if img.shape[2] == 4 else None


@dataclass
class Scene:
    views: list[View]
    splits: dict[str, list[int]]  # split name -> indices into views; always "train" and "test"
    source: str = ""
    format: str = ""
    background: np.ndarray = field(default_factory=lambda: np.ones(3, dtype=np.float32))
    near: float | None = None
    far: float | None = None
    points: np.ndarray | None = None  # (N, 3) sparse points when the source has them
    point_colors: np.ndarray | None = None  # (N, 3) in [0, 1]
    has_alpha: bool = False
    world_scale: float = 1.0  # world length = internal length x world_scale (gsgs_engine.io.world_scale)
    resolution_scale: float = 1.0  # image scale the views were loaded at (load_scene's, after its max_side cap)

    def split(self, name: str) -> list[View]:
        if name not in self.splits:
            raise GsgsError(f"{self.source}: no split named {name!r}; available: {', '.join(sorted(self.splits))}")
        return [self.views[i] for i in self.splits[name]]

    @property
    def train(self) -> list[View]:
        return self.split("train")

    @property
    def test(self) -> list[View]:
        return self.split("test")

    @property
    def has_time(self) -> bool:
        return any(v.time is not None for v in self.views)

    def camera_extent(self, split: str = "train") -> tuple[np.ndarray, float]:
        """Centre and radius of the camera centres (3DGS's `cameras_extent`, 1.1 x max distance)."""
        centers = np.stack([v.camera.center for v in self.split(split)])
        c = centers.mean(axis=0)
        radius = float(np.linalg.norm(centers - c, axis=1).max()) * 1.1
        return c, max(radius, 1e-6)
