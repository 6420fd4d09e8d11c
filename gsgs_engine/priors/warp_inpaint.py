"""The weights-free generator: training photos warped into a pseudo view, holes inpainted.

For every pseudo-view pixel the render covers, its rendered depth places a surface point;
each training photo that sees that point (its own rendered depth agrees: visibility
check) contributes its colour, nearer cameras weighted more. Covered pixels that no
photo sees (disocclusions, content past every photo's edge) are holes, handled as
`hole_fill` says:

- "background": grown from the far side of the hole only. A disocclusion is
  background that a nearer surface hid, so the nearer surface's pixels along the hole's rim
  are never sources (they keep their colour): the fill continues the background instead of
  smearing the occluder across the hole.
- "telea" (default): OpenCV's Telea inpainting from every pixel around the hole.
- "mask": no fill; the holes are left out of the pseudo view's loss (its trusted mask).

Pixels the render leaves empty keep the render (the scene background) or, for scenes
without one, are inpainted too. Real, fast, and geometry-consistent by construction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera
from gsgs_engine.priors.warp import backward_warp

COVERED_ALPHA = 0.5
HOLE_FILLS = ("telea", "background", "mask")
RIM_PX = 5  # background-first fill: how far around a hole the rim's depths are compared (pixels)
NEARER = 0.9  # a rim pixel nearer than this x the farthest rim depth around it is the occluder


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


def occluder_rim(holes: torch.Tensor, z: torch.Tensor, rim_px: int = RIM_PX, nearer: float = NEARER
                 ) -> torch.Tensor:
    """(H, W) bool: the occluding side of each hole. The rim of a hole is the pixels outside it within
    `rim_px` of it with a surface depth `z` (0 = none); a rim pixel nearer than `nearer` x the
    farthest rim depth of the same hole is on the occluder's side."""
    import cv2

    if not bool(holes.any()):
        return torch.zeros_like(holes)
    k = np.ones((2 * rim_px + 1, 2 * rim_px + 1), np.uint8)
    h = holes.cpu().numpy()
    zn = z.detach().cpu().numpy().astype(np.float64)
    grown = cv2.dilate(h.astype(np.uint8), k)
    count, labels = cv2.connectedComponents(grown, connectivity=8)
    rim = grown.astype(bool) & ~h & (zn > 0)
    far = np.zeros(count)
    np.maximum.at(far, labels[rim], zn[rim])
    occluder = rim & (zn < nearer * far[labels])
    return torch.from_numpy(occluder).to(holes.device)


def grow_from(image: torch.Tensor, holes: torch.Tensor, sources: torch.Tensor) -> torch.Tensor:
    """Fill `holes` by growing inward from `sources` only: each pass gives every hole pixel touching a
    filled or source pixel (8-neighbourhood) the mean of those neighbours. Holes that no source
    reaches are left to Telea inpainting."""
    import cv2

    img = image.detach().cpu().numpy().astype(np.float32)
    h = holes.cpu().numpy().copy()
    known = sources.cpu().numpy() & ~h
    value = np.where(known[..., None], img, 0.0).astype(np.float32)
    weight = known.astype(np.float32)
    while h.any():
        s = cv2.boxFilter(value, -1, (3, 3), normalize=False)
        w = cv2.boxFilter(weight, -1, (3, 3), normalize=False)
        step = h & (w > 0)
        if not step.any():
            break
        value[step] = s[step] / w[step][:, None]
        weight[step] = 1.0
        h &= ~step
    out = image.clone()
    done = torch.from_numpy(holes.cpu().numpy() & ~h).to(image.device)
    out[done] = torch.from_numpy(value).to(image.dtype).to(image.device)[done]
    return inpaint(out, torch.from_numpy(h).to(image.device)) if h.any() else out


def fill_holes(image: torch.Tensor, holes: torch.Tensor, z: torch.Tensor, how: str = "background") -> torch.Tensor:
    """`image` with its `holes` filled: "background" grown from the far side only (the occluder's rim
    is never a source), "telea" inpainted from every side, "mask" not at all."""
    if how == "mask" or not bool(holes.any()):
        return image
    if how == "telea":
        return inpaint(image, holes)
    if how != "background":
        raise GsgsError(f"hole_fill must be one of {', '.join(HOLE_FILLS)}, got {how!r}")
    return grow_from(image, holes, ~occluder_rim(holes, z))


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


def warp_inpaint(camera: Camera, render: torch.Tensor, depth: torch.Tensor, alpha: torch.Tensor,
                 photos: list[TrainingPhoto], rel_tolerance: float = 0.05, fill_empty: bool = False,
                 hole_fill: str = "telea") -> tuple[torch.Tensor, dict, torch.Tensor]:
    """A pseudo-view image (H, W, 3) from the training photos, its coverage statistics and its trusted
    mask (H, W bool: the pixels the loss should use; all but the holes under hole_fill="mask").

    `fill_empty` (scenes without a real background, e.g. photos): pixels the render leaves
    empty are inpainted too, from the content around them, rather than left as background.
    `hole_fill`: how covered pixels that no photo sees are handled (module docstring).
    """
    if hole_fill not in HOLE_FILLS:
        raise GsgsError(f"hole_fill must be one of {', '.join(HOLE_FILLS)}, got {hole_fill!r}")
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
    if hole_fill == "telea":  # holes and empty pixels in one inpainting (a hole beside an empty area sees both)
        image = inpaint(image, holes | empty)
    else:
        image = inpaint(fill_holes(image, holes, z, hole_fill), empty)
    trusted = ~holes if hole_fill == "mask" else torch.ones_like(holes)
    n = max(int(covered.sum()), 1)
    stats = {"covered": float(covered.float().mean()), "warped": float(seen.sum()) / n,
             "inpainted": float(holes.sum()) / n if hole_fill != "mask" else 0.0,
             "masked": float(holes.sum()) / n if hole_fill == "mask" else 0.0,
             "empty_filled": float(empty.float().mean())}
    return image.clamp(0, 1), stats, trusted
