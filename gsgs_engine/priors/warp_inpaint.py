"""The weights-free generator: training photos warped into a pseudo view, holes inpainted.

For every pseudo-view pixel the render covers, its rendered depth places a surface point;
each training photo that sees that point (its own rendered depth agrees: visibility
check) contributes its colour, nearer cameras weighted more. Covered pixels that no
photo sees (disocclusions) are filled with OpenCV inpainting; pixels the render leaves
empty keep the render (the scene background) or, for scenes without one, are inpainted
too. Real, fast, and geometry-consistent by construction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from gsgs_engine.cameras import Camera
from gsgs_engine.priors.config import PriorConfig
from gsgs_engine.priors.warp import backward_warp

COVERED_ALPHA = 0.5


def surface_depth(depth: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """Expected depth of the covered part of each pixel (eq. 7 divided by alpha); 0 where empty."""
    covered = alpha > COVERED_ALPHA
    return torch.where(covered, depth / alpha.clamp_min(1e-6), torch.zeros_like(depth))


@dataclass
class TrainingPhoto:
    camera: Camera
    image: torch.Tensor  # (H, W, 3) ground truth
    depth: torch.Tensor  # (H, W) surface depth rendered at this view (0 = empty)


def inpaint(image: torch.Tensor, holes: torch.Tensor, radius: int = 3) -> torch.Tensor:
    """Fill `holes` (H, W bool) of an (H, W, 3) [0, 1] image with OpenCV's Telea inpainting."""
    if not bool(holes.any()):
        return image
    import cv2

    u8 = (image.detach().cpu().numpy().clip(0, 1) * 255 + 0.5).astype(np.uint8)
    mask = holes.cpu().numpy().astype(np.uint8) * 255
    filled = cv2.inpaint(u8, mask, radius, cv2.INPAINT_TELEA).astype(np.float32) / 255.0
    out = image.clone()
    h = holes.to(image.device)
    out[h] = torch.from_numpy(filled).to(image.dtype).to(image.device)[h]
    return out


def fill_empty_depth(z: torch.Tensor, radius: int = 5) -> torch.Tensor:
    """Surface depth (H, W, 0 = empty) with the empty pixels filled from the covered ones around them
    (OpenCV Telea on the float map), for placing new Gaussians where a view shows nothing."""
    empty = z <= 0
    if not bool(empty.any()) or bool(empty.all()):
        return z
    import cv2

    d = z.detach().cpu().numpy().astype(np.float32)
    filled = cv2.inpaint(d, empty.cpu().numpy().astype(np.uint8) * 255, radius, cv2.INPAINT_TELEA)
    lo, hi = float(d[d > 0].min()), float(d[d > 0].max())
    out = torch.from_numpy(np.clip(filled, lo, hi)).to(z)
    return torch.where(empty, out, z)


def warp_photos(camera: Camera, render: torch.Tensor, depth: torch.Tensor, alpha: torch.Tensor,
                photos: list[TrainingPhoto], rel_tolerance: float = PriorConfig.warp_tolerance, fill_empty: bool = False
                ) -> tuple[torch.Tensor, torch.Tensor, dict]:
    """warp_inpaint's first half: the pseudo view with the photos warped in (the render elsewhere), the pixels still
    to inpaint (H, W bool) and the coverage statistics."""
    z = surface_depth(depth.detach(), alpha.detach())
    covered = z > 0
    acc = torch.zeros_like(render)
    wsum = torch.zeros_like(z)
    for photo in photos:
        sampled, valid = backward_warp(camera, z, photo.camera, photo.image.to(render.dtype),
                                       photo.depth.to(z.dtype), rel_tolerance)
        d2 = float(np.sum((camera.center - photo.camera.center) ** 2))
        w = valid.to(z.dtype) / (d2 + 1e-6)
        acc += sampled * w[..., None]
        wsum += w
    seen = wsum > 0
    image = render.detach().clone()
    image[seen] = acc[seen] / wsum[seen][:, None]
    holes = covered & ~seen
    empty = ~covered if fill_empty else torch.zeros_like(covered)
    n = max(int(covered.sum()), 1)
    stats = {"covered": float(covered.float().mean()), "warped": float(seen.sum()) / n,
             "inpainted": float(holes.sum()) / n, "empty_filled": float(empty.float().mean())}
    return image, holes | empty, stats


def warp_inpaint(camera: Camera, render: torch.Tensor, depth: torch.Tensor, alpha: torch.Tensor,
                 photos: list[TrainingPhoto], rel_tolerance: float = PriorConfig.warp_tolerance, fill_empty: bool = False
                 ) -> tuple[torch.Tensor, dict]:
    """A pseudo-view image (H, W, 3) from the training photos; returns it with coverage statistics.

    `fill_empty` (scenes without a real background, e.g. photos): pixels the render leaves
    empty are inpainted too, from the content around them, rather than left as background.
    """
    image, holes, stats = warp_photos(camera, render, depth, alpha, photos, rel_tolerance, fill_empty)
    return inpaint(image, holes).clamp(0, 1), stats


def on_threads(fn, items: list, workers: int) -> list:
    """[fn(item) for item in items] on up to `workers` threads, in order. For OpenCV's work (inpainting, PNG
    encoding), which runs without Python's lock; each result is the same as computed alone."""
    if workers <= 1 or len(items) <= 1:
        return [fn(item) for item in items]
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=min(workers, len(items))) as pool:
        return list(pool.map(fn, items))


def inpaint_all(images: list[torch.Tensor], holes: list[torch.Tensor], workers: int) -> list[torch.Tensor]:
    """inpaint() of every (image, holes) pair, clamped to [0, 1], on up to `workers` threads (a prior round's 16
    ring views spend most of their generation time here: a forward-facing round 3-5 s on the 2-core machine)."""
    return on_threads(lambda pair: inpaint(*pair).clamp(0, 1), list(zip(images, holes)), workers)
