"""Dense initial points from the sparse training views with known poses: multi-view stereo on the CPU.

What "MVS init" means in the sparse-view papers (vanilla 3DGS on LLFF 3 views: 17.43 dB with the SfM
points of the 3 views, 19.22 with MVS points): per training view,
1. a plane sweep over inverse depth between the view's near and far depth (from the sparse SfM points
   when there are any, else the cameras' near/far, else the scene's box), at a reduced working size;
2. photometric cost: 1 - zero-mean normalised cross-correlation (NCC) of a square window between the
   reference image and each source image warped through the fronto-parallel plane; occlusion-robust
   aggregation over sources (the mean of the best half); winner-take-all over depth, refined to a
   sub-sample inverse depth by a parabola through the neighbouring costs;
3. a geometric-consistency check: a pixel's 3D point is projected into another view, that view's
   depth is read there, lifted back and reprojected into the reference; the pixel is kept when this
   round trip lands within `reproj_px` pixels and `rel_depth` relative depth for >= `min_consistent`
   other views (1 below 5 views, else 2);
4. the kept pixels of every view fused into coloured world points, subsampled to `max_points`.
Where stereo finds little (textureless views, too few overlaps), points spread through the views'
frustums between near and far, coloured by the pixel they sit on, fill up to `fallback_points` (in proportion to
the share of `min_points` the stereo missed: fallback_count).

Entry for the trainer: `dense_initial_model(scene, train_views, sh_degree, seed)`.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from typing import Callable

import numpy as np
import torch
import torch.nn.functional as F

from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera
from gsgs_engine.init import cache as init_cache
from gsgs_engine.init.views import nearest_sources, working_view


@dataclass
class MVSConfig:
    max_side: int = 256  # working size of the sweep (longest image side, pixels) ...
    sweep_budget: float = 1.0e8  # ... reduced further so views x sources x pixels x depths stays below this
    num_depths: int = 96  # inverse-depth samples between near and far
    window: int = 7  # NCC window side (working pixels)
    max_sources: int = 3  # source views per reference (nearest by camera-centre distance and viewing angle)
    min_ncc: float = 0.5  # a pixel's best aggregated NCC must reach this
    min_texture: float = 2e-4  # variance of the reference window (grey levels in [0, 1]) below this: no match
    reproj_px: float = 1.0  # geometric consistency: round-trip reprojection error (working pixels)
    rel_depth: float = 0.01  # geometric consistency: relative depth difference
    # other views that must agree; None: 1 below 5 views (3-view LLFF has only 2 others), else 2. Measured on the
    # NeRF-synthetic 8 views: the share of points inside all 25 test silhouettes rises from 78 / 73 % (lego / chair,
    # 1 view) to 88 / 78 % (2 views) for half the points (gsgs bench mvs-points)
    min_consistent: int | None = None
    max_points: int = 100_000
    min_points: int = 2000  # fewer fused points than this: add the frustum fallback
    fallback_points: int = 20_000
    depth_chunk: int = 16  # depth planes warped at once (memory)
    alpha_threshold: float = 0.5  # RGBA views: pixels below this alpha are background, never points
    # optical-flow matches triangulated with the known poses, fused with the stereo points before the max_points
    # subsample (gsgs_engine.init.flow_matches): None (off), "dis" or "deepflow"
    flow: str | None = None

    def validate(self) -> "MVSConfig":
        if self.max_side < 16 or self.num_depths < 3 or self.window < 3 or self.window % 2 == 0:
            raise GsgsError(f"mvs: max_side >= 16, num_depths >= 3 and an odd window >= 3 are needed, got {self}")
        from gsgs_engine.init.flow_matches import FLOW_METHODS

        if self.flow is not None and self.flow not in FLOW_METHODS:
            raise GsgsError(f"mvs: flow must be off or one of {', '.join(FLOW_METHODS)}, got {self.flow!r}")
        if self.max_points < 1 or (self.min_consistent is not None and self.min_consistent < 0) or self.max_sources < 1:
            raise GsgsError(f"mvs: max_points >= 1, min_consistent >= 0 and max_sources >= 1 are needed, got {self}")
        return self


@dataclass
class DenseInit:
    points: np.ndarray  # (N, 3) float32 world points
    colors: np.ndarray  # (N, 3) float32 in [0, 1]
    method: str  # "mvs", "mvs+fallback" or "fallback"
    reason: str
    stats: dict = field(default_factory=dict)


@dataclass
class _WorkView:
    camera: Camera  # scaled to the working size
    gray: torch.Tensor  # (H, W)
    rgb: torch.Tensor  # (H, W, 3)
    mask: torch.Tensor  # (H, W) bool: foreground (alpha) pixels
    near: float
    far: float


def working_side(views: list, cfg: MVSConfig) -> int:
    """Longest side of the working images: max_side, or less when the sweep would exceed the budget."""
    cams = [v.camera for v in views]
    sources = min(cfg.max_sources, max(1, len(cams) - 1))
    longest = max(max(c.width, c.height) for c in cams)
    mean_area = float(np.mean([c.width * c.height for c in cams]))
    side = min(cfg.max_side, longest)
    per_pixel = len(cams) * sources * cfg.num_depths
    if per_pixel * mean_area * (side / longest) ** 2 > cfg.sweep_budget:
        side = int(longest * math.sqrt(cfg.sweep_budget / (per_pixel * mean_area)))
    return max(16, side)


def depth_range(camera: Camera, sparse_points: np.ndarray | None, bounds: tuple[np.ndarray, np.ndarray] | None,
                near: float | None, far: float | None) -> tuple[float, float]:
    """Near and far depth for a view's sweep: the 1st-99th percentile of the sparse points in front of it
    (widened by 20 %), else the camera's / scene's near and far, else the depths of the scene box's corners."""
    if sparse_points is not None and len(sparse_points) >= 20:
        uv, z = camera.project(sparse_points)
        inside = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)
        if inside.sum() >= 20:
            lo, hi = np.percentile(z[inside], [1, 99])
            return float(lo / 1.2), float(hi * 1.2)
    near = camera.near if camera.near is not None else near
    far = camera.far if camera.far is not None else far
    if near is not None and far is not None and 0 < near < far:
        return float(near), float(far)
    if bounds is None:
        raise GsgsError(f"mvs: view {camera.name!r} has no near/far and no scene bounds to sweep between")
    lo, hi = bounds
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    z = camera.to_camera(corners)[:, 2]
    far_z = float(z.max())
    if far_z <= 0:
        raise GsgsError(f"mvs: the scene box lies behind view {camera.name!r}; check the poses")
    return max(float(z.min()), far_z * 1e-2), far_z


def _box_pools(x: torch.Tensor, window: int) -> torch.Tensor:
    """`_box` as two separable average pools (replicated borders): a NaN or Inf stays inside its window."""
    pad = window // 2
    x = F.avg_pool2d(F.pad(x, (pad, pad, 0, 0), mode="replicate"), (1, window), stride=1)
    return F.avg_pool2d(F.pad(x, (0, 0, pad, pad), mode="replicate"), (window, 1), stride=1)


def _box(x: torch.Tensor, window: int) -> torch.Tensor:
    """Mean over a window x window neighbourhood (replicated borders), (B, C, H, W) -> same shape.

    OpenCV's running-sum box filter, plane by plane: the same means as two separable average pools up to float
    rounding (~1e-7), at about a tenth of their time (the pools were two thirds of the sweep's time). A running sum
    would carry a NaN or Inf past its window, so such input takes the pools, whose damage stays inside it.
    """
    if x.dtype not in (torch.float32, torch.float64) or not bool(torch.isfinite(x).all()):
        return _box_pools(x, window)
    import cv2

    planes = x.detach().contiguous().reshape(-1, x.shape[-2], x.shape[-1]).numpy()
    out = np.empty_like(planes)
    for i in range(planes.shape[0]):
        cv2.boxFilter(planes[i], -1, (window, window), dst=out[i], normalize=True, borderType=cv2.BORDER_REPLICATE)
    return torch.from_numpy(out).reshape(x.shape)


def _pixel_grid(cam: Camera) -> torch.Tensor:
    """Homogeneous pixel centres (3, H*W), row-major, centre of the top-left pixel at (0.5, 0.5)."""
    v, u = torch.meshgrid(torch.arange(cam.height, dtype=torch.float64) + 0.5,
                          torch.arange(cam.width, dtype=torch.float64) + 0.5, indexing="ij")
    return torch.stack([u.reshape(-1), v.reshape(-1), torch.ones(u.numel(), dtype=torch.float64)])


def _relative_projection(ref: Camera, src: Camera) -> tuple[torch.Tensor, torch.Tensor]:
    """(A, b) with src pixel-homogeneous = depth * A @ ref_pixel + b for a ref pixel at that depth."""
    M = src.R @ ref.R.T
    A = src.K @ M @ np.linalg.inv(ref.K)
    b = src.K @ (src.t - M @ ref.t)
    return torch.from_numpy(A), torch.from_numpy(b)


def _sample(img: torch.Tensor, u: torch.Tensor, v: torch.Tensor, width: int, height: int,
            mode: str = "bilinear") -> torch.Tensor:
    """Sample (C, H, W) image at continuous pixel coordinates (B, N) -> (B, C, N); outside -> 0."""
    grid = torch.stack([u / width * 2 - 1, v / height * 2 - 1], dim=-1).float()[:, None]  # (B, 1, N, 2)
    out = F.grid_sample(img[None].expand(u.shape[0], -1, -1, -1), grid, mode=mode, padding_mode="zeros",
                        align_corners=False)
    return out[:, :, 0]


def sweep_costs(ref: _WorkView, src: _WorkView, inv_depths: torch.Tensor, cfg: MVSConfig) -> torch.Tensor:
    """1 - NCC of the reference window against the source warped through each fronto-parallel plane,
    (D, H, W); 2 (the worst) where the window leaves the source image or lies behind it."""
    H, W = ref.gray.shape
    A, b = _relative_projection(ref.camera, src.camera)
    rays = (A @ _pixel_grid(ref.camera)).float()  # (3, N)
    b = b.float()
    r = ref.gray[None, None].float()
    mu_r = _box(r, cfg.window)
    var_r = (_box(r * r, cfg.window) - mu_r**2).clamp_min(0)
    out = torch.empty(len(inv_depths), H, W, dtype=torch.float32)
    src_img = src.gray[None].float()
    for start in range(0, len(inv_depths), cfg.depth_chunk):
        d = (1.0 / inv_depths[start:start + cfg.depth_chunk]).float()
        P = d[:, None, None] * rays[None] + b[None, :, None]  # (Dc, 3, N)
        z = P[:, 2]
        z_safe = torch.where(z > 1e-6, z, torch.ones_like(z))
        u, v = P[:, 0] / z_safe, P[:, 1] / z_safe
        sw, sh = src.camera.width, src.camera.height
        valid = (z > 1e-6) & (u >= 0) & (u <= sw) & (v >= 0) & (v <= sh)
        warped = _sample(src_img, u, v, sw, sh).reshape(-1, 1, H, W)
        valid = valid.reshape(-1, 1, H, W).float()
        mu_w, e_ww, e_rw, coverage = _box(torch.cat([warped, warped * warped, warped * r, valid], dim=1),
                                          cfg.window).split(1, dim=1)
        var_w = (e_ww - mu_w**2).clamp_min(0)
        ncc = (e_rw - mu_w * mu_r) / torch.sqrt(var_w * var_r + 1e-10)
        cost = torch.where(coverage > 0.999, (1.0 - ncc).clamp(0.0, 2.0), torch.full_like(ncc, 2.0))
        out[start:start + len(d)] = cost[:, 0]
    return out


def estimate_depth(index: int, views: list[_WorkView], cfg: MVSConfig) -> tuple[torch.Tensor, torch.Tensor]:
    """Depth (H, W; NaN where rejected) and best aggregated NCC of view `index`."""
    ref = views[index]
    sources = nearest_sources(index, [v.camera for v in views], cfg.max_sources)
    inv = torch.linspace(1.0 / ref.far, 1.0 / ref.near, cfg.num_depths, dtype=torch.float64)
    costs = torch.stack([sweep_costs(ref, views[j], inv, cfg) for j in sources])  # (S, D, H, W)
    k = max(1, len(sources) // 2)
    # occlusion-robust: the best half of the sources (one of three: their minimum, without a sort)
    agg = costs.min(dim=0).values if k == 1 else costs.sort(dim=0).values[:k].mean(dim=0)
    best_cost, idx = agg.min(dim=0)
    # sub-sample refinement: a parabola through the costs at idx-1, idx, idx+1
    lo = (idx - 1).clamp(0, cfg.num_depths - 1)
    hi = (idx + 1).clamp(0, cfg.num_depths - 1)
    c0, cl, ch = best_cost, agg.gather(0, lo[None])[0], agg.gather(0, hi[None])[0]
    denom = cl - 2 * c0 + ch
    interior = (idx > 0) & (idx < cfg.num_depths - 1) & (denom > 1e-9)
    offset = torch.where(interior, 0.5 * (cl - ch) / denom.clamp_min(1e-9), torch.zeros_like(c0)).clamp(-0.5, 0.5)
    step = float(inv[1] - inv[0])
    inv_best = inv.float()[idx] + offset * step
    depth = 1.0 / inv_best.clamp_min(1e-12)
    g = ref.gray[None, None].double()
    texture = (_box(g * g, cfg.window) - _box(g, cfg.window) ** 2)[0, 0].float()
    ok = interior & (1.0 - best_cost >= cfg.min_ncc) & (texture >= cfg.min_texture) & ref.mask
    depth = torch.where(ok, depth, torch.full_like(depth, float("nan")))
    return depth, 1.0 - best_cost


def _backproject(cam: Camera, depth: torch.Tensor) -> torch.Tensor:
    """World points (H*W, 3) of a depth map (NaN stays NaN)."""
    rays = torch.from_numpy(np.linalg.inv(cam.K)) @ _pixel_grid(cam)  # (3, N)
    pc = rays * depth.reshape(1, -1).double()
    R, t = torch.from_numpy(cam.R), torch.from_numpy(cam.t)
    return (R.T @ (pc - t[:, None])).T


def _project(cam: Camera, pts: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    R, t, K = (torch.from_numpy(a) for a in (cam.R, cam.t, cam.K))
    pc = pts @ R.T + t
    z = pc[:, 2]
    z_safe = torch.where(z > 1e-12, z, torch.ones_like(z))
    return K[0, 0] * pc[:, 0] / z_safe + K[0, 2], K[1, 1] * pc[:, 1] / z_safe + K[1, 2], z


def consistent_views(index: int, depths: list[torch.Tensor], views: list[_WorkView], cfg: MVSConfig) -> torch.Tensor:
    """How many other views confirm each pixel's depth by a projection round trip, (H, W) int."""
    ref = views[index].camera
    H, W = depths[index].shape
    pts = _backproject(ref, depths[index])
    grid = _pixel_grid(ref)
    count = torch.zeros(H * W, dtype=torch.int32)
    for j, other in enumerate(views):
        if j == index:
            continue
        cam = other.camera
        u, v, z = _project(cam, pts)
        ok = torch.isfinite(z) & (z > 0) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        ui = torch.nan_to_num(u, nan=0.0).clamp(0, cam.width - 1).long()
        vi = torch.nan_to_num(v, nan=0.0).clamp(0, cam.height - 1).long()
        d_other = depths[j][vi, ui].double()
        ok &= torch.isfinite(d_other)
        hom = torch.stack([ui.double() + 0.5, vi.double() + 0.5, torch.ones_like(u)])
        back_cam = (torch.from_numpy(np.linalg.inv(cam.K)) @ hom) * d_other[None]
        back = (torch.from_numpy(cam.R).T @ (back_cam - torch.from_numpy(cam.t)[:, None])).T
        u2, v2, z2 = _project(ref, back)
        err = torch.sqrt((u2 - grid[0]) ** 2 + (v2 - grid[1]) ** 2)
        d_ref = depths[index].reshape(-1).double()
        rel = (z2 - d_ref).abs() / d_ref
        ok &= (err < cfg.reproj_px) & (rel < cfg.rel_depth)
        count += ok.to(torch.int32)
    return count.reshape(H, W)


def fallback_count(stereo_points: int, cfg: MVSConfig) -> int:
    """Frustum points to add to `stereo_points` kept points: cfg.fallback_points x the share of cfg.min_points missing."""
    if stereo_points >= cfg.min_points:
        return 0
    return int(round(cfg.fallback_points * (1.0 - stereo_points / cfg.min_points)))


def frustum_points(views: list[_WorkView], n: int, generator: torch.Generator) -> tuple[np.ndarray, np.ndarray]:
    """n points spread through the views' frustums (uniform in inverse depth between near and far) on
    foreground pixels, coloured by those pixels."""
    pts, cols = [], []
    per_view = [n // len(views) + (1 if i < n % len(views) else 0) for i in range(len(views))]
    for view, m in zip(views, per_view):
        fg = torch.nonzero(view.mask.reshape(-1)).reshape(-1)
        if m == 0 or len(fg) == 0:
            continue
        pick = fg[torch.randint(len(fg), (m,), generator=generator)]
        s = torch.rand(m, generator=generator, dtype=torch.float64)
        inv = 1.0 / view.far + s * (1.0 / view.near - 1.0 / view.far)
        depth = torch.full((view.gray.numel(),), float("nan"), dtype=torch.float64)
        # A pixel drawn more than once takes its last draw's depth, every draw of it the same value: an indexed
        # write of different values to one pixel is a race on several threads (the points differed run to run).
        last = torch.full((view.gray.numel(),), -1, dtype=torch.long)
        last.scatter_reduce_(0, pick, torch.arange(m), "amax")
        depth[pick] = (1.0 / inv)[last[pick]]
        world = _backproject(view.camera, depth)[pick]
        pts.append(world.numpy())
        cols.append(view.rgb.reshape(-1, 3)[pick].numpy())
    if not pts:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32)
    return np.concatenate(pts).astype(np.float32), np.concatenate(cols).astype(np.float32)


def dense_points(train_views: list, sparse_points: np.ndarray | None = None, near: float | None = None,
                 far: float | None = None, bounds: tuple[np.ndarray, np.ndarray] | None = None,
                 config: MVSConfig | None = None, seed: int = 0,
                 log: Callable[[str], None] = print) -> DenseInit:
    """Fused MVS points of the training views (scene.View objects with known poses), with the fallback."""
    cfg = (config or MVSConfig()).validate()
    if len(train_views) < 1:
        raise GsgsError("mvs: no training views")
    t0 = time.perf_counter()
    views = []
    side = working_side(train_views, cfg)
    for view in train_views:
        cam, rgb, mask = working_view(view, side, cfg.alpha_threshold)
        lo, hi = depth_range(view.camera, sparse_points, bounds, near, far)
        rgb_t = torch.from_numpy(rgb)
        gray = rgb_t @ torch.tensor([0.299, 0.587, 0.114])
        views.append(_WorkView(cam, gray, rgb_t, torch.from_numpy(mask), lo, hi))
    # the same working views, settings and code as an earlier run: its points (gsgs_engine.init.cache); the optical-flow
    # matches read the full-size views, so a run with them is always computed
    digest = _cache_key(views, cfg, seed) if cfg.flow is None else None
    hit = init_cache.load_arrays("mvs", digest) if digest is not None else None
    if hit is not None:
        arrays, meta = hit
        stats = dict(meta["stats"], cached=True, computed_seconds=meta["stats"].get("seconds"),
                     seconds=round(time.perf_counter() - t0, 2))
        reason = f"{meta['reason']}; reused from the init cache (computed in {stats['computed_seconds']} s before)"
        log(f"mvs: {meta['method']}: {len(arrays['points'])} points in {stats['seconds']:.1f} s ({reason}, "
            f"{digest[:12]})")
        return DenseInit(arrays["points"], arrays["colors"], meta["method"], reason, stats)
    result = _sweep_and_fuse(views, train_views, cfg, seed, t0, log)
    if digest is not None:
        init_cache.store_arrays("mvs", digest, {"points": result.points, "colors": result.colors},
                                {"method": result.method, "reason": result.reason, "stats": result.stats})
    return result


def _cache_key(views: list[_WorkView], cfg: MVSConfig, seed: int) -> str:
    """The init cache's key of a dense initialisation: the working views as the sweep reads them (cameras, pixels,
    masks, depth ranges), the settings, the seed, the thread count (a sum's order can follow it), the code and the
    libraries' versions."""
    parts = []
    for v in views:
        parts += [v.camera.to_dict(), v.rgb.numpy(), v.mask.numpy(), float(v.near), float(v.far)]
    return init_cache.key("mvs", asdict(cfg), int(seed), torch.get_num_threads(), *parts,
                          init_cache.source_digest(__name__, nearest_sources.__module__),
                          init_cache.package_versions("torch", "numpy"))


def _sweep_and_fuse(views: list[_WorkView], train_views: list, cfg: MVSConfig, seed: int, t0: float,
                    log: Callable[[str], None]) -> DenseInit:
    """dense_points' computation: the sweep and consistency check of every view, the fusion, the fallback."""
    generator = torch.Generator().manual_seed(int(seed))
    stats: dict = {"config": asdict(cfg), "views": []}
    pts_all, cols_all = [], []
    if len(views) >= 2:
        depths = []
        for i, view in enumerate(views):
            depth, _ = estimate_depth(i, views, cfg)
            depths.append(depth)
            log(f"mvs: view {i + 1}/{len(views)} {view.camera.name}: {int(torch.isfinite(depth).sum())} matched pixels "
                f"of {depth.numel()} (depth {view.near:.3g}..{view.far:.3g}, {time.perf_counter() - t0:.1f} s)")
        need = cfg.min_consistent if cfg.min_consistent is not None else (1 if len(views) < 5 else 2)
        stats["min_consistent"] = need
        for i, view in enumerate(views):
            count = consistent_views(i, depths, views, cfg)
            keep = torch.isfinite(depths[i]) & (count >= need)
            flat = keep.reshape(-1)
            pts_all.append(_backproject(view.camera, depths[i])[flat].float().numpy())
            cols_all.append(view.rgb.reshape(-1, 3)[flat].numpy())
            stats["views"].append({"name": view.camera.name, "size": [view.camera.width, view.camera.height],
                                   "near": view.near, "far": view.far,
                                   "matched": int(torch.isfinite(depths[i]).sum()), "consistent": int(flat.sum())})
    n_stereo = int(sum(len(p) for p in pts_all))
    if cfg.flow is not None and len(views) >= 2:
        from gsgs_engine.init.flow_matches import FlowConfig, flow_points

        fp = flow_points(train_views, FlowConfig(method=cfg.flow, alpha_threshold=cfg.alpha_threshold), log=log)
        pts_all.append(fp.points)
        cols_all.append(fp.colors)
        stats["flow"] = {k: v for k, v in fp.stats.items() if k != "config"}
    points = np.concatenate(pts_all) if pts_all else np.zeros((0, 3), np.float32)
    colors = np.concatenate(cols_all) if cols_all else np.zeros((0, 3), np.float32)
    n_mvs = len(points)
    if n_mvs > cfg.max_points:
        pick = torch.randperm(n_mvs, generator=generator)[:cfg.max_points].sort().values.numpy()
        points, colors = points[pick], colors[pick]
    method, reason = "mvs", (f"{len(points)} multi-view-stereo points from the {len(views)} training views "
                             f"({n_stereo} geometrically consistent at {views[0].camera.width}x{views[0].camera.height}"
                             + (f", {n_mvs - n_stereo} optical-flow matches ({cfg.flow})" if "flow" in stats else "")
                             + ")")
    if len(points) < cfg.min_points:
        # As many frustum points as the stereo falls short of min_points, in proportion: all fallback_points for views
        # that do not match at all, few for a sweep just under the minimum. (Adding all of them below the minimum and
        # none above it was a cliff: 3 Panoptic cameras keep 1,871-1,991 points on some frames, 2,045-2,049 on others,
        # and the frames that got 20,000 random points scored 16.5-16.8 dB against 19.8; docs/dynamic_panoptic.md.)
        fp, fc = frustum_points(views, fallback_count(len(points), cfg), generator)
        why = f"stereo kept {len(points)} points (< {cfg.min_points})" if len(views) >= 2 else "one view: no stereo"
        method = "mvs+fallback" if len(points) else "fallback"
        reason = f"{why}; added {len(fp)} points spread through the views' frustums between near and far"
        points, colors = np.concatenate([points, fp]), np.concatenate([colors, fc])
    stats.update({"mvs_points": n_stereo, "flow_points": n_mvs - n_stereo, "points": len(points), "seconds": round(time.perf_counter() - t0, 2)})
    log(f"mvs: {method}: {len(points)} points in {stats['seconds']:.1f} s ({reason})")
    return DenseInit(points.astype(np.float32), np.clip(colors, 0, 1).astype(np.float32), method, reason, stats)


def dense_initial_model(scene, train_views: list, sh_degree: int, seed: int = 0, config: MVSConfig | None = None,
                        use_sfm: bool = True, log: Callable[[str], None] = print):
    """(GaussianModel, InitInfo) from MVS points of the training views plus their SfM points.

    The SfM points (triangulated from the training views only) set each view's depth range and join
    the result; without them the cameras' near/far or the scene's box bound the sweep."""
    from gsgs_engine.gaussians import GaussianModel, InitInfo

    points, colors, method, reason = dense_and_sparse_points(scene, train_views, seed, config, use_sfm, log)
    model = GaussianModel.from_points(points, colors, sh_degree)
    return model, InitInfo(method, len(points), reason)


def trainer_dense_init(trainer, log: Callable[[str], None] = print):
    """`dense_initial_model` of a static trainer's scene and training views, at its config's seed, SH degree
    and sweep size (what `gsgs train --init mvs` starts from)."""
    cfg = trainer.config
    return dense_initial_model(trainer.scene, trainer.train_views, cfg.sh_degree, seed=cfg.seed,
                               config=MVSConfig(max_side=cfg.mvs_max_side, flow=mvs_flow_method(cfg.mvs_flow)),
                               log=log)


def mvs_flow_method(setting: str) -> str | None:
    """The `mvs_flow` setting ("off", "dis", "deepflow") -> MVSConfig.flow."""
    return None if setting in (None, "off", "none") else str(setting)


def dense_and_sparse_points(scene, train_views: list, seed: int = 0, config: MVSConfig | None = None,
                            use_sfm: bool = True, log: Callable[[str], None] = print):
    """(points, colours, method, reason): MVS points of the training views plus their SfM points (see
    dense_initial_model); a 4D run calls it once per frame (gsgs_engine.train.dynamic)."""
    from gsgs_engine.gaussians import scene_bounds_from_cameras

    sparse, sparse_cols = None, None
    if use_sfm and len(train_views) >= 2:
        try:
            from gsgs_engine.sfm import triangulate_known_poses

            sparse, sparse_cols = triangulate_known_poses(train_views)
            sparse = np.asarray(sparse, dtype=np.float32).reshape(-1, 3)
            sparse_cols = np.asarray(sparse_cols, dtype=np.float32).reshape(-1, 3)
        except (GsgsError, ImportError) as exc:
            log(f"mvs: no SfM points for the depth range ({exc})")
            sparse = None
    bounds = scene_bounds_from_cameras([v.camera for v in train_views], scene.near, scene.far)
    dense = dense_points(train_views, sparse_points=sparse, near=scene.near, far=scene.far, bounds=bounds,
                         config=config, seed=seed, log=log)
    points, colors = dense.points, dense.colors
    reason = dense.reason
    if sparse is not None and len(sparse):
        points, colors = np.concatenate([points, sparse]), np.concatenate([colors, sparse_cols])
        reason += f"; plus {len(sparse)} SfM points of the training views"
    if len(points) == 0:
        raise GsgsError("mvs: no initial points (no stereo matches, no foreground pixels)")
    return points, colors, dense.method, reason
