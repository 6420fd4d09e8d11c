"""Dense correspondences between the training views from optical flow, triangulated with the known poses.

A second dense initialisation beside the plane sweep of `gsgs_engine.init.mvs` (issue 30 item 3; the
idea of Binocular3DGS's matcher initialisation, without its learned matcher). For every training view
(the reference) and its nearest other views (the sources):
1. dense optical flow reference -> source and back (OpenCV's DIS or contrib's DeepFlow, on grey levels
   at a working size);
2. forward-backward check: a pixel is matched when following the flow there and back lands within
   `fb_px` working pixels of where it started (occlusions and mismatches fail it);
3. triangulation of each matched pixel pair with the known poses (the midpoint of the two rays'
   closest approach), kept when the point lies in front of both cameras, reprojects within
   `reproj_px` working pixels in both views (a match off the epipolar line fails this) and the rays
   meet at `min_angle_deg` or more (a small angle leaves the depth undetermined);
4. with two or more sources, a pixel is kept only where two sources' depths agree within `agree_rel`
   (their mean is kept): one flow field can be wrong consistently, two independent ones rarely are.
The kept pixels (every `stride`-th in each direction) become coloured world points.

`flow_points(train_views, config)` -> FlowPoints (points, colours, per-view statistics).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from typing import Callable

import numpy as np

from gsgs_engine import GsgsError
from gsgs_engine.init.views import nearest_sources, working_view

FLOW_METHODS = ("dis", "deepflow")


@dataclass
class FlowConfig:
    method: str = "dis"  # "dis" (OpenCV core, fast) or "deepflow" (opencv-contrib, slower, larger motions)
    max_side: int = 512  # working size (longest image side, pixels)
    fb_px: float = 1.0  # forward-backward consistency (working pixels)
    reproj_px: float = 1.0  # triangulated point must reproject within this in both views (working pixels)
    min_angle_deg: float = 1.0  # the two rays must meet at this angle or more
    agree_rel: float = 0.01  # two sources' depths must agree within this (relative)
    min_sources: int = 2  # 2: two sources must agree; 1: one pair's checks suffice (two that disagree still drop it)
    max_sources: int = 2  # sources per reference view (nearest by viewing direction, then centre distance)
    stride: int = 2  # keep every stride-th pixel in x and y
    alpha_threshold: float = 0.5  # RGBA views: pixels below this alpha are background, never points

    def validate(self) -> "FlowConfig":
        if self.method not in FLOW_METHODS:
            raise GsgsError(f"flow matches: method must be one of {', '.join(FLOW_METHODS)}, got {self.method!r}")
        if self.max_side < 16 or self.stride < 1 or self.max_sources < 1 or self.min_sources not in (1, 2):
            raise GsgsError("flow matches: max_side >= 16, stride >= 1, max_sources >= 1 and min_sources 1 or 2 are "
                            f"needed, got {self}")
        if not (self.fb_px > 0 and self.reproj_px > 0 and self.agree_rel > 0 and 0 <= self.min_angle_deg < 90):
            raise GsgsError(f"flow matches: positive tolerances and an angle in [0, 90) are needed, got {self}")
        return self


@dataclass
class FlowPoints:
    points: np.ndarray  # (N, 3) float32 world points
    colors: np.ndarray  # (N, 3) float32 in [0, 1]
    stats: dict = field(default_factory=dict)


def _grey_u8(rgb: np.ndarray) -> np.ndarray:
    grey = rgb[..., :3].astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)
    return np.clip(np.nan_to_num(grey, nan=0.0) * 255.0 + 0.5, 0, 255).astype(np.uint8)


def dense_flow(a: np.ndarray, b: np.ndarray, method: str) -> np.ndarray:
    """Optical flow (H, W, 2) float32 from grey image a to grey image b (uint8, same size)."""
    import cv2

    if method == "dis":
        dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
        flow = dis.calc(a, b, None)
    else:
        flow = cv2.optflow.createOptFlow_DeepFlow().calc(a, b, None)
    return np.nan_to_num(flow.astype(np.float32), nan=1e6, posinf=1e6, neginf=1e6)


def forward_backward_ok(fwd: np.ndarray, bwd: np.ndarray, tol: float) -> np.ndarray:
    """(H, W) bool: following fwd then bwd (sampled bilinearly at the landing point) returns within tol pixels."""
    import cv2

    h, w = fwd.shape[:2]
    xs, ys = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    mx, my = xs + fwd[..., 0], ys + fwd[..., 1]
    back = cv2.remap(bwd, mx, my, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=1e6)
    err = np.hypot(fwd[..., 0] + back[..., 0], fwd[..., 1] + back[..., 1])
    inside = (mx >= 0) & (mx <= w - 1) & (my >= 0) & (my <= h - 1)
    return inside & (err < tol)


def triangulate_midpoint(cam_a, cam_b, uv_a: np.ndarray, uv_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World points (N, 3) at the midpoint of the closest approach of the rays through pixel positions uv_a
    (in cam_a) and uv_b (in cam_b), and the angle (N,) between the rays in degrees. Parallel rays give NaN."""
    def rays(cam, uv):
        hom = np.concatenate([uv.astype(np.float64), np.ones((len(uv), 1))], axis=1)
        d = (np.linalg.inv(cam.K) @ hom.T).T @ cam.R  # camera -> world: R^T d, as row vectors d @ R
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    ca, cb = np.asarray(cam_a.center, np.float64), np.asarray(cam_b.center, np.float64)
    da, db = rays(cam_a, uv_a), rays(cam_b, uv_b)
    w0 = ca - cb
    b = np.sum(da * db, axis=1)
    d, e = da @ w0, db @ w0
    denom = 1.0 - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(denom > 1e-12, (b * e - d) / denom, np.nan)
        t = np.where(denom > 1e-12, (e - b * d) / denom, np.nan)
    pts = 0.5 * ((ca + s[:, None] * da) + (cb + t[:, None] * db))
    angle = np.degrees(np.arccos(np.clip(b, -1.0, 1.0)))
    return pts, angle


def pair_depths(ref_cam, src_cam, fwd: np.ndarray, bwd: np.ndarray, pick: np.ndarray, cfg: FlowConfig):
    """Depth in the reference camera (N,) of the picked pixels (flat indices), NaN where a check fails."""
    h, w = fwd.shape[:2]
    ys, xs = np.divmod(pick, w)
    uv_a = np.stack([xs + 0.5, ys + 0.5], axis=1)
    f = fwd.reshape(-1, 2)[pick].astype(np.float64)
    uv_b = uv_a + f
    ok = forward_backward_ok(fwd, bwd, cfg.fb_px).reshape(-1)[pick]
    pts, angle = triangulate_midpoint(ref_cam, src_cam, uv_a, uv_b)
    ok &= np.isfinite(pts).all(axis=1) & (angle >= cfg.min_angle_deg)
    depths = []
    for cam, uv in ((ref_cam, uv_a), (src_cam, uv_b)):
        proj, z = cam.project(np.nan_to_num(pts))
        ok &= (z > 0) & (np.hypot(*(proj - uv).T) < cfg.reproj_px)
        depths.append(z)
    return np.where(ok, depths[0], np.nan)


def combine_depths(d: np.ndarray, agree_rel: float, min_sources: int) -> np.ndarray:
    """One depth per pixel from the sources' depths (S, N; NaN = no match): the mean of the first two sources
    that agree within agree_rel; with min_sources 1 also a lone source's depth where no other source matched.
    Two sources that both matched and disagree give NaN either way."""
    best = np.full(d.shape[1], np.nan)
    for a in range(len(d)):
        for b in range(a + 1, len(d)):
            agree = np.abs(d[a] - d[b]) <= agree_rel * np.minimum(d[a], d[b])  # False where either is NaN
            best = np.where(np.isnan(best) & agree, 0.5 * (d[a] + d[b]), best)
    if min_sources <= 1:  # a pixel only one source matched (two that matched and disagree stay NaN)
        lone = np.isfinite(d).sum(axis=0) == 1
        best = np.where(lone, np.max(np.where(np.isfinite(d), d, -np.inf), axis=0), best)
    return best


def flow_points(train_views: list, config: FlowConfig | None = None,
                log: Callable[[str], None] = print) -> FlowPoints:
    """Triangulated optical-flow matches of the training views (scene.View objects with known poses)."""
    import cv2

    cfg = (config or FlowConfig()).validate()
    if len(train_views) < 2:
        return FlowPoints(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32),
                          {"config": asdict(cfg), "views": [], "points": 0, "reason": "one view: no matches"})
    t0 = time.perf_counter()
    cams, rgbs, greys, masks = [], [], [], []
    for view in train_views:
        small, rgb, mask = working_view(view, cfg.max_side, cfg.alpha_threshold)
        cams.append(small)
        rgbs.append(rgb)
        greys.append(_grey_u8(rgb))
        masks.append(mask)
    flows: dict[tuple[int, int], np.ndarray] = {}

    def flow(i: int, j: int) -> np.ndarray:
        if (i, j) not in flows:
            if greys[i].shape != greys[j].shape:  # different sizes: resample the source onto the reference grid
                flows[(i, j)] = dense_flow(greys[i], cv2.resize(greys[j], greys[i].shape[::-1]), cfg.method)
                flows[(i, j)] *= np.array([greys[j].shape[1] / greys[i].shape[1],
                                           greys[j].shape[0] / greys[i].shape[0]], np.float32)
            else:
                flows[(i, j)] = dense_flow(greys[i], greys[j], cfg.method)
        return flows[(i, j)]

    pts_all, cols_all, per_view = [], [], []
    for i, cam in enumerate(cams):
        h, w = greys[i].shape
        ys, xs = np.mgrid[cfg.stride // 2:h:cfg.stride, cfg.stride // 2:w:cfg.stride]
        pick = (ys * w + xs).reshape(-1)
        pick = pick[masks[i].reshape(-1)[pick]]
        depths = []
        for j in nearest_sources(i, cams, cfg.max_sources):
            if greys[i].shape != greys[j].shape:
                continue  # the flow check below needs both fields on one grid; mixed sizes: skip that pair
            depths.append(pair_depths(cam, cams[j], flow(i, j), flow(j, i), pick, cfg))
        if not depths:
            per_view.append({"name": cam.name, "matched": 0, "kept": 0})
            continue
        depth = combine_depths(np.stack(depths), cfg.agree_rel, min(cfg.min_sources, len(depths)))
        keep = np.isfinite(depth)
        sel = pick[keep]
        sy, sx = np.divmod(sel, w)
        uv = np.stack([sx + 0.5, sy + 0.5, np.ones(len(sel))], axis=1)
        pc = (np.linalg.inv(cam.K) @ uv.T) * depth[keep][None]
        world = (cam.R.T @ (pc - np.asarray(cam.t, np.float64).reshape(3, 1))).T
        pts_all.append(world.astype(np.float32))
        cols_all.append(rgbs[i].reshape(-1, 3)[sel])
        per_view.append({"name": cam.name, "size": [w, h], "pixels": int(len(pick)),
                         "matched_per_source": [int(np.isfinite(x).sum()) for x in depths], "kept": int(keep.sum())})
    points = np.concatenate(pts_all) if pts_all else np.zeros((0, 3), np.float32)
    colors = np.concatenate(cols_all) if cols_all else np.zeros((0, 3), np.float32)
    stats = {"config": asdict(cfg), "views": per_view, "points": int(len(points)),
             "seconds": round(time.perf_counter() - t0, 2)}
    log(f"flow matches ({cfg.method}): {len(points)} points from {len(cams)} views in {stats['seconds']:.1f} s")
    return FlowPoints(points.astype(np.float32), np.clip(colors, 0, 1).astype(np.float32), stats)
