"""A textured sphere behind the splats: the wall of an inward shell, learned from the photos.

A dome or studio whose cameras hang on its walls (an inward shell, docs/inward_rigs.md) films those walls from
the other side. Splats reconstruct them poorly (each wall is far from most cameras and seen at grazing angles),
and where no splat covers a pixel of a novel view the render shows the background colour: a flat grey where the
photo shows panels, dots and lights. Here the background is a sphere through the cameras (centre: the point
nearest every optical axis, `cameras.focus_point`; radius: the cameras' mean distance from it) carrying an
equirectangular texture that training learns. A pixel's background is the texture where its ray leaves the
sphere (the far intersection, so a camera on or inside the shell sees the wall across from it; a ray that
misses a sphere the camera is outside of takes the point of its closest approach). The render composites it
under the splats' remaining transmittance (3DGS's eq. 3 with a per-pixel background):

    C = sum_i c_i a_i T_i + T_N bg(ray),   T_N = 1 - alpha

so the texture learns from the pixels the splats leave uncovered, and the splats' alpha gets the gradient of the
texture behind them. The texture is in logit space (its colours stay in (0, 1)), starts at the scene's
background colour (the photos' mean on an inward shell) and has its own Adam (`LEARNING_RATE`).
Measured on the Panoptic capture: docs/dynamic_panoptic.md, "Session 35".
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera, focus_point

# Adam, on the texture's logits. Screened on the Panoptic dome (session 36, docs/dynamic_panoptic.md): the 4D model
# with 6 cameras, seeds 0 / 1, gave 0.15: 20.31 / 20.88 dB, 0.05 (session 35's first value): 22.06 / 22.24,
# 0.02: 22.21 / 22.97, 0.01: 23.39 / 23.37, 0.005: 22.72 / 23.45; at 0.01 against 0.05 (seed 0) 3 cameras 19.69 ->
# 19.94, 9 cameras 24.84 -> 25.12, the still frame with 9 cameras (gsgs train --prior auto) 22.00 -> 23.30.
LEARNING_RATE = 0.01
DEFAULT_WIDTH = 256  # texels around the equator (the height is half: 1.4 degrees a texel either way)
TEXTURE_FILE = "background_sphere.png"


def check_width(width: int, what: str = "background_sphere") -> int:
    width = int(width)
    if width != 0 and not (16 <= width <= 8192 and width % 2 == 0):
        raise GsgsError(f"{what} must be 0 (off) or an even texture width of 16..8192 texels (got {width})")
    return width


def sphere_through(cameras: list[Camera]) -> tuple[np.ndarray, float]:
    """(centre, radius) of the sphere through the cameras: centred where their optical axes meet."""
    if not cameras:
        raise GsgsError("background sphere: no cameras to place it by")
    centre, _ = focus_point(cameras)
    radius = float(np.mean([np.linalg.norm(c.center - centre) for c in cameras]))
    if not (np.all(np.isfinite(centre)) and math.isfinite(radius) and radius > 0):
        raise GsgsError("background sphere: the cameras do not surround a point (all at one place, or their axes "
                        "do not meet); use another background")
    return np.asarray(centre, np.float64), radius


def ray_texture_coords(camera: Camera, centre: np.ndarray, radius: float) -> torch.Tensor:
    """(1, H, W, 2) grid_sample coordinates (longitude, latitude in [-1, 1]) of where each pixel's ray leaves
    the sphere (float64 arithmetic, float32 result)."""
    o, d = camera.pixel_rays()
    o = torch.from_numpy(np.array(o, dtype=np.float64)) - torch.from_numpy(np.asarray(centre, np.float64))
    d = torch.from_numpy(np.array(d, dtype=np.float64))
    od = (o * d).sum(-1)
    # |o + s d| = R: s = -o.d +- sqrt((o.d)^2 - |o|^2 + R^2); the far root, or the closest approach on a miss
    disc = (od * od - (o * o).sum(-1) + radius * radius).clamp_min(0.0)
    s = (-od + disc.sqrt()).clamp_min(0.0)
    p = o + s[..., None] * d
    norm = p.norm(dim=-1, keepdim=True)
    p = torch.where(norm > 1e-12, p / norm.clamp_min(1e-12), torch.tensor([0.0, 0.0, 1.0], dtype=p.dtype))
    lon = torch.atan2(p[..., 1], p[..., 0]) / math.pi
    lat = torch.asin(p[..., 2].clamp(-1.0, 1.0)) / (math.pi / 2)
    return torch.stack([lon, -lat], -1).float()[None]  # row 0 of the texture is the top (+z)


class BackgroundSphere:
    """The texture (3, H, W) as logits, the sphere's centre and radius (the trainer's units), a cache of the
    cameras' texture coordinates."""

    def __init__(self, centre, radius: float, logits: torch.Tensor):
        self.centre = np.asarray(centre, np.float64).reshape(3)
        self.radius = float(radius)
        self.logits = logits.detach().clone().float().requires_grad_(True)
        self._coords: dict = {}

    @classmethod
    def through(cls, cameras: list[Camera], colour, width: int = DEFAULT_WIDTH, device="cpu") -> "BackgroundSphere":
        centre, radius = sphere_through(cameras)
        width = check_width(width)
        c = torch.as_tensor(np.asarray(colour, np.float32)).reshape(3, 1, 1).clamp(1e-3, 1 - 1e-3)
        return cls(centre, radius, torch.logit(c).expand(3, width // 2, width).to(device))

    @property
    def size(self) -> tuple[int, int]:
        return int(self.logits.shape[2]), int(self.logits.shape[1])

    def texture(self) -> torch.Tensor:
        """(3, H, W) colours in [0, 1]."""
        return torch.sigmoid(self.logits)

    def coords(self, camera: Camera) -> torch.Tensor:
        key = (camera.width, camera.height, camera.R.tobytes(), camera.t.tobytes(), camera.fx, camera.fy, camera.cx,
               camera.cy)
        grid = self._coords.get(key)
        if grid is None:
            if len(self._coords) >= 256:  # novel cameras (binocular shifts, pseudo views) come and go
                self._coords.pop(next(iter(self._coords)))
            grid = self._coords[key] = ray_texture_coords(camera, self.centre, self.radius).to(self.logits.device)
        return grid

    def image(self, camera: Camera) -> torch.Tensor:
        """(H, W, 3) background colour of each pixel of `camera`."""
        img = F.grid_sample(self.texture()[None], self.coords(camera), mode="bilinear", padding_mode="border",
                            align_corners=False)
        return img[0].permute(1, 2, 0)

    def composite(self, out, camera: Camera, background: torch.Tensor):
        """`out` (a RenderOutput composited over the constant `background`) with the sphere behind it instead:
        colour + (1 - alpha) (sphere - background). Differentiable in the texture and in the render."""
        bg = self.image(camera).to(out.color.dtype)
        const = torch.as_tensor(background, dtype=out.color.dtype, device=out.color.device).reshape(1, 1, 3)
        out.color = out.color + (1.0 - out.alpha)[..., None] * (bg - const)
        return out

    # -- checkpoint and result ------------------------------------------------------------------------------
    def state_dict(self) -> dict:
        return {"centre": torch.as_tensor(self.centre), "radius": torch.tensor(self.radius, dtype=torch.float64),
                "logits": self.logits.detach().cpu()}

    @classmethod
    def from_state_dict(cls, state: dict, device="cpu") -> "BackgroundSphere":
        return cls(state["centre"].numpy(), float(state["radius"]), state["logits"].to(device))

    def describe(self, world_scale: float = 1.0) -> dict:
        """The record metrics.json keeps (world units: the trainer's x world_scale)."""
        w, h = self.size
        return {"file": TEXTURE_FILE, "centre": [float(x) * world_scale for x in self.centre],
                "radius": self.radius * world_scale, "width": w, "height": h,
                "mapping": "equirectangular: column = longitude atan2(y, x) from -180 deg (left) to 180, row = "
                           "latitude from +90 deg (top, +z) to -90, of the direction from the centre"}

    def write_texture(self, path) -> None:
        import cv2

        rgb = (self.texture().detach().cpu().permute(1, 2, 0).numpy() * 65535.0 + 0.5).astype(np.uint16)
        if not cv2.imwrite(str(path), rgb[..., ::-1]):
            raise GsgsError(f"{path}: could not write the background sphere's texture")

    @classmethod
    def from_record(cls, record: dict, folder, world_scale: float = 1.0, device="cpu") -> "BackgroundSphere":
        """The sphere `describe` recorded, its texture read from `folder` (for `gsgs eval`)."""
        import cv2

        path = Path(folder) / record.get("file", TEXTURE_FILE)
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None or img.ndim != 3 or img.shape[2] != 3:
            raise GsgsError(f"{path}: the background sphere's texture is missing or not an RGB image; the result's "
                            "metrics.json names it: copy it back beside the PLY or re-export the run")
        scale = 65535.0 if img.dtype == np.uint16 else 255.0
        tex = torch.from_numpy(img[..., ::-1].astype(np.float32) / scale).permute(2, 0, 1).clamp(1e-4, 1 - 1e-4)
        return cls(np.asarray(record["centre"], np.float64) / world_scale, float(record["radius"]) / world_scale,
                   torch.logit(tex).to(device))
