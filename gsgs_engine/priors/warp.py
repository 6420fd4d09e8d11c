"""Moving pixels between posed views with depth (METHOD.md "warp").

Two directions, both z-buffered or visibility-checked, both returning a validity mask:
- `forward_warp`: an image and its depth at one camera -> splatted into another camera
  (unproject, transform, project, nearest-pixel z-buffer). Used by the geometry-aware
  loss (eq. 6) to move a pseudo-view render into its nearest training view.
- `backward_warp`: for every pixel of a target camera with known depth, sample a source
  image (bilinear), keeping only pixels that the source camera actually sees (its own
  depth agrees). Used by the warp-inpaint generator.
Depth here is z-depth along the camera's +z axis (what eq. 7 renders, divided by alpha).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from gsgs_engine.cameras import Camera


def _tensor(a, like: torch.Tensor) -> torch.Tensor:
    return torch.as_tensor(a, dtype=like.dtype, device=like.device)


def unproject(camera: Camera, depth: torch.Tensor) -> torch.Tensor:
    """Depth map (H, W) -> world points (H, W, 3) through every pixel centre."""
    h, w = depth.shape
    v, u = torch.meshgrid(torch.arange(h, dtype=depth.dtype, device=depth.device) + 0.5,
                          torch.arange(w, dtype=depth.dtype, device=depth.device) + 0.5, indexing="ij")
    x = (u - camera.cx) / camera.fx * depth
    y = (v - camera.cy) / camera.fy * depth
    p_cam = torch.stack([x, y, depth], dim=-1)
    R, t = _tensor(camera.R, depth), _tensor(camera.t, depth)
    return (p_cam - t) @ R  # R^T (p - t) for row vectors


def project(camera: Camera, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """World points (..., 3) -> pixel coordinates (..., 2) and z-depth (...)."""
    R, t = _tensor(camera.R, points), _tensor(camera.t, points)
    p = points @ R.T + t
    z = p[..., 2]
    safe_z = torch.where(z.abs() > 1e-9, z, torch.full_like(z, 1e-9))
    u = camera.fx * p[..., 0] / safe_z + camera.cx
    v = camera.fy * p[..., 1] / safe_z + camera.cy
    return torch.stack([u, v], dim=-1), z


def forward_warp(image: torch.Tensor, depth: torch.Tensor, src: Camera, dst: Camera,
                 src_mask: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Splat `image` (H, W, C) with `depth` (H, W) from camera `src` into camera `dst`.

    Returns (warped image (H', W', C), warped depth (H', W'), valid mask (H', W')). Each
    destination pixel keeps the nearest source point that lands in it (z-buffer); pixels
    nothing lands in are invalid (holes, disocclusions, outside the source view).
    """
    h2, w2 = dst.height, dst.width
    pts = unproject(src, depth).reshape(-1, 3)
    uv, z = project(dst, pts)
    colors = image.reshape(-1, image.shape[-1])
    ok = torch.isfinite(z) & (z > 1e-6) & (depth.reshape(-1) > 0) & torch.isfinite(uv).all(dim=-1)
    if src_mask is not None:
        ok &= src_mask.reshape(-1).bool()
    px = torch.floor(uv[:, 0]).long()
    py = torch.floor(uv[:, 1]).long()
    ok &= (px >= 0) & (px < w2) & (py >= 0) & (py < h2)
    idx = (py * w2 + px)[ok]
    z_ok, c_ok = z[ok], colors[ok]
    zbuf = torch.full((h2 * w2,), float("inf"), dtype=depth.dtype, device=depth.device)
    zbuf.scatter_reduce_(0, idx, z_ok, reduce="amin")
    # Among the points that reach a pixel, the one at the z-buffer depth wins (ties: last write).
    winner = z_ok <= zbuf[idx]
    out = torch.zeros((h2 * w2, image.shape[-1]), dtype=image.dtype, device=image.device)
    out[idx[winner]] = c_ok[winner]
    valid = torch.isfinite(zbuf)
    zbuf = torch.where(valid, zbuf, torch.zeros_like(zbuf))
    return out.reshape(h2, w2, -1), zbuf.reshape(h2, w2), valid.reshape(h2, w2)


def backward_warp(dst: Camera, dst_depth: torch.Tensor, src: Camera, src_image: torch.Tensor,
                  src_depth: torch.Tensor | None = None, rel_tolerance: float = 0.05
                  ) -> tuple[torch.Tensor, torch.Tensor]:
    """Colour every `dst` pixel of known depth by sampling `src_image` where it projects.

    Returns (image (H, W, C), valid mask (H, W)). A pixel is valid when it projects inside the
    source image in front of the camera and, if `src_depth` is given, the source sees that
    surface (its depth agrees within `rel_tolerance`): occluded pixels are not copied.
    """
    pts = unproject(dst, dst_depth)
    uv, z = project(src, pts)
    hs, ws = src_image.shape[:2]
    # grid_sample's align_corners=False maps -1/+1 to the outer pixel edges: exactly u / W.
    grid = torch.stack([uv[..., 0] / ws * 2 - 1, uv[..., 1] / hs * 2 - 1], dim=-1)[None].to(src_image.dtype)
    grid = torch.nan_to_num(grid, nan=-2.0, posinf=-2.0, neginf=-2.0)
    img = src_image.permute(2, 0, 1)[None]
    sampled = F.grid_sample(img, grid, mode="bilinear", padding_mode="border", align_corners=False)[0].permute(1, 2, 0)
    valid = (dst_depth > 0) & (z > 1e-6) & (grid.abs() <= 1).all(dim=-1)[0]
    if src_depth is not None:
        seen = F.grid_sample(src_depth[None, None].to(src_image.dtype), grid, mode="nearest",
                             padding_mode="border", align_corners=False)[0, 0]
        valid &= (seen > 0) & ((z - seen).abs() <= rel_tolerance * z.abs())
    return sampled, valid
