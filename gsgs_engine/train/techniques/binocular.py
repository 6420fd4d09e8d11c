"""Binocular self-consistency (Binocular3DGS) as a training technique.

From `start_fraction` of the run on, each step moves the training camera along its own x axis
by a random baseline b (|b| uniform in [0, max_baseline], random sign), renders that shifted
view, and warps it back into the training view with the depth rendered at the training view
(for a pure x shift the warp is the disparity d = f b / z, which `warp_shifted_to_view` applies directly;
`priors.warp.backward_warp`'s general reprojection reduces to it). Two terms:

- "binocular_l1": L1 between the warped shifted render and the training photo, over the pixels
  the warp sees (inside the shifted image, in front of it, where the training render is opaque),
  averaged over all pixels as in the paper's code (weight `weight`, default 1.0);
- "binocular_smooth": edge-aware smoothness of the disparity f |b| / z (pixels), small weight
  (`smooth_weight`, default 0.05): disparity gradients cost less across image edges.

The gradient reaches both the shifted render's colours and the training view's depth (through
the sampling positions), so geometry that is wrong between the views gets a photometric signal
from a single photo. Binocular3DGS's defaults: baseline 0.4 in scene units for scenes of about
4 units' depth (Blender) and the shifted view from 2/3 (LLFF 20k/30k) or 4/7 (Blender 4k/7k) of
training. Here the baseline is relative to the scene, so that one setting serves every scene:
0.1 x its depth (the median distance from the initial points to their nearest training camera),
but never more than 0.75 x the rig's own baseline (the mean distance from a training camera to
its nearest neighbour): the virtual stereo partner stays within what the capture spans. Both are
measured once at install and checkpointed; the start is 0.6 of the run. On object orbits the
depth term decides (Blender lego: 0.34, about Binocular3DGS's 0.4; the cap would be 1.8); on a
forward-facing capture whose subject stands far before its background the cap does (LLFF flower:
depth 70 would give 7.0 against cameras 3.1 apart; capped, 2.3), which measured +0.34 dB there
with LLFF horns unchanged (depth 3.3, cap 3.3; docs/sparse_techniques.md).

With `scale` < 1 the shifted view is rendered at that fraction of the training view's size; the
warp samples it (bilinearly) at the training view's full-resolution pixels, so the training depth
keeps its full-resolution gradient while the extra render costs a fraction of a full one.

With `bands` = k > 1 each step supervises one of k horizontal bands of the training view (bands
of whole 16-pixel tile rows, picked at random each step, so every row is supervised equally often
over the run): the shifted camera is cropped to the band's rows (its principal point moved, its height
the band's), which a pure x shift keeps inside the band, so the extra render costs about 1 / k of a
full one. The terms are the band's means; the bands differ in height by at most a tile row, so their
expectation over the band drawn is close to the full view's mean (equal for equal bands).
A band renders its rows as the full view does, except within a few rows of an inner band edge, where
a Gaussian centred beyond the edge meets the projection's frustum clamp there (the colour moves by up
to ~1e-3 on the tests' scene; tested).

The shifted render goes through `Trainer.render_for_training` (dropout applies to it too) but is
not added to `ctx.renders`: as in the paper's code, densification statistics come from the
training view only. Its random baseline comes from the trainer's seeded generator.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch
import torch.nn.functional as F

from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera
from gsgs_engine.train.fused_binocular import binocular_l1, x_shift
from gsgs_engine.train.technique import StepContext, Technique

DEFAULT_WEIGHT = 1.0
DEFAULT_SMOOTH_WEIGHT = 0.05
DEFAULT_BASELINE_FRACTION = 0.1  # of the scene depth: 0.34 units on Blender's objects (Binocular3DGS: 0.4)
DEFAULT_RIG_FRACTION = 0.75  # cap: of the mean distance from a training camera to its nearest neighbour
DEFAULT_START_FRACTION = 0.6
DEFAULT_SCALE = 1.0  # render size of the shifted view, a fraction of the training view's
DEFAULT_BANDS = 1  # the training view in one band (the whole view) per step
BAND_ALIGN = 16  # band edges on the rasteriser's tile rows
MIN_OPAQUE = 0.5  # a training pixel takes part where the rendered alpha says a surface is there


def shifted_camera(camera: Camera, baseline: float) -> Camera:
    """`camera` moved by `baseline` along its own x axis (x_cam' = x_cam - (b, 0, 0)); same intrinsics."""
    t = np.asarray(camera.t, dtype=np.float64) - np.array([baseline, 0.0, 0.0])
    return replace(camera, t=t, name=f"{camera.name}@x{baseline:+.4g}")


def band_rows(height: int, bands: int, index: int) -> tuple[int, int]:
    """Rows [y0, y1) of band `index` of `bands` horizontal bands of an image `height` rows high: edges at
    multiples of BAND_ALIGN rows (the rasteriser's tiles), as even as that allows; never empty while
    height >= bands * BAND_ALIGN (else the edges fall on whole rows)."""
    align = BAND_ALIGN if height >= bands * BAND_ALIGN else 1

    def edge(i: int) -> int:
        return height if i >= bands else int(round(i * height / bands / align)) * align

    return edge(index), edge(index + 1)


def band_camera(camera: Camera, y0: int, y1: int) -> Camera:
    """`camera` cropped to its rows [y0, y1): the same pose and focal lengths, the principal point moved."""
    return camera.cropped_rows(y0, y1)


def surface_depth(depth: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """z-depth of the rendered surface: the render's alpha-weighted depth divided by its alpha."""
    return depth / alpha.clamp_min(1e-6)


def warp_shifted_to_view(camera: Camera, depth: torch.Tensor, shifted: Camera, shifted_image: torch.Tensor
                         ) -> tuple[torch.Tensor, torch.Tensor]:
    """The shifted view's image resampled into `camera` with `camera`'s z-depth: (image (H, W, 3), valid (H, W)).

    `shifted` is `camera` moved along its own x axis (shifted_camera), possibly resized (Camera.scaled): a pixel
    (u, v) at z-depth z lands at u' = fx' ((u - cx) / fx - b / z) + cx', v' = fy' (v - cy) / fy + cy' (rectified
    stereo: the disparity f b / z along x alone). That is what priors.warp.backward_warp's reprojection through
    world space reduces to, in a few image-sized operations instead of two 3x3 products per pixel and their
    backward (tested equal). Any other pair of cameras goes through backward_warp."""
    from gsgs_engine.priors.warp import backward_warp

    baseline = x_shift(camera, shifted)
    if baseline is None:
        return backward_warp(camera, depth, shifted, shifted_image)
    h, w = depth.shape
    u = torch.arange(w, dtype=depth.dtype, device=depth.device) + 0.5
    v = torch.arange(h, dtype=depth.dtype, device=depth.device) + 0.5
    safe_z = torch.where(depth.abs() > 1e-9, depth, torch.full_like(depth, 1e-9))
    x_over_z = ((u - camera.cx) / camera.fx)[None, :] - baseline / safe_z  # (H, W): x / z in the shifted camera
    hs, ws = shifted_image.shape[:2]
    # grid_sample's align_corners=False maps -1/+1 to the outer pixel edges: exactly u / W.
    gx = (shifted.fx * x_over_z + shifted.cx) / ws * 2 - 1
    gy = ((shifted.fy * (v - camera.cy) / camera.fy + shifted.cy) / hs * 2 - 1)[:, None].expand(h, w)
    grid = torch.nan_to_num(torch.stack([gx, gy], dim=-1)[None].to(shifted_image.dtype), nan=-2.0, posinf=-2.0,
                            neginf=-2.0)
    img = shifted_image.permute(2, 0, 1)[None]
    sampled = F.grid_sample(img, grid, mode="bilinear", padding_mode="border", align_corners=False)[0].permute(1, 2, 0)
    valid = (depth > 1e-6) & (grid.abs() <= 1).all(dim=-1)[0]
    return sampled, valid


def masked_l1(image: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """mean over all pixels and channels of |image - target| where `mask` (H, W) holds."""
    return ((image - target).abs() * mask[..., None].to(image.dtype)).mean()


def edge_aware_smoothness(disparity: torch.Tensor, image: torch.Tensor) -> torch.Tensor:
    """mean |d disparity / dx| e^{-|dI/dx|} + the same along y (|dI| averaged over channels).

    Central differences of both, as the paper's code uses: a disparity step that coincides with
    an image edge is cheap, one in a flat image region is not.
    """
    def dx(t):
        return (t[:, 2:] - t[:, :-2]) / 2

    def dy(t):
        return (t[2:] - t[:-2]) / 2

    gx = dx(image).abs().mean(-1)
    gy = dy(image).abs().mean(-1)
    return (dx(disparity).abs() * torch.exp(-gx)).mean() + (dy(disparity).abs() * torch.exp(-gy)).mean()


def rig_baseline(camera_centers) -> float | None:
    """Mean distance from each camera centre to its nearest other one (None for fewer than 2 cameras)."""
    c = np.asarray(camera_centers, dtype=np.float64).reshape(-1, 3)
    if len(c) < 2:
        return None
    d = np.linalg.norm(c[:, None] - c[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    return float(d.min(axis=1).mean())


def nearest_camera_distances(points, camera_centers, who: str) -> np.ndarray:
    """Distance from each finite point to its nearest camera centre (at most 20k points, evenly sampled).

    `who` names the technique in the error raised when no point is finite."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    centers = np.asarray(camera_centers, dtype=np.float64).reshape(-1, 3)
    if len(pts) == 0:
        raise GsgsError(f"{who}: the model has no finite Gaussian positions to measure the scene depth from")
    if len(pts) > 20000:
        pts = pts[np.linspace(0, len(pts) - 1, 20000).astype(int)]
    return np.linalg.norm(pts[:, None] - centers[None], axis=-1).min(axis=1)


def scene_depth(points, camera_centers) -> float:
    """Median distance from `points` to their nearest camera centre (the scene's depth scale)."""
    return float(np.median(nearest_camera_distances(points, camera_centers, "binocular")))


class BinocularConsistency(Technique):
    name = "binocular"

    def __init__(self, weight: float = DEFAULT_WEIGHT, smooth_weight: float = DEFAULT_SMOOTH_WEIGHT,
                 baseline_fraction: float = DEFAULT_BASELINE_FRACTION, start_fraction: float = DEFAULT_START_FRACTION,
                 max_baseline: float | None = None, rig_fraction: float = DEFAULT_RIG_FRACTION,
                 scale: float = DEFAULT_SCALE, every: int = 1, bands: int = DEFAULT_BANDS):
        if not (isinstance(bands, int) and bands >= 1):
            raise GsgsError(f"binocular: bands must be a whole number >= 1 (got {bands!r})")
        self.bands = bands
        if not (isinstance(every, int) and every >= 1):
            raise GsgsError(f"binocular: every must be a whole number of steps >= 1 (got {every!r})")
        self.every = every
        if not 0.0 < scale <= 1.0:
            raise GsgsError(f"binocular: the shifted view's render scale must be in (0, 1] (got {scale})")
        self.scale = float(scale)
        if weight < 0 or smooth_weight < 0:
            raise GsgsError(f"binocular: weights must be >= 0 (got {weight}, {smooth_weight})")
        if not 0.0 <= start_fraction < 1.0:
            raise GsgsError(f"binocular: start_fraction must be in [0, 1) (got {start_fraction})")
        if not rig_fraction > 0:
            raise GsgsError(f"binocular: rig_fraction must be positive (got {rig_fraction}); a large value "
                            "lifts the cap")
        self.rig_fraction = float(rig_fraction)
        self.rig_baseline: float | None = None
        self.weight, self.smooth_weight = float(weight), float(smooth_weight)
        self.baseline_fraction, self.start_fraction = float(baseline_fraction), float(start_fraction)
        self.max_baseline = max_baseline  # scene units; None: measured at install (class docstring)
        self.scene_depth: float | None = None
        self.start = 1
        self.steps = 0
        self.last_valid = 0.0

    def install(self, trainer) -> None:
        self.start = max(1, int(round(self.start_fraction * trainer.config.iters)) + 1)
        if self.max_baseline is None:
            centres = [v.camera.center for v in trainer.train_views]
            self.scene_depth = scene_depth(trainer.model.means.detach().cpu().numpy(), centres)
            self.rig_baseline = rig_baseline(centres)
            self.max_baseline = self.baseline_fraction * self.scene_depth
            if self.rig_baseline is not None and self.rig_baseline > 0:
                self.max_baseline = min(self.max_baseline, self.rig_fraction * self.rig_baseline)
        if not (np.isfinite(self.max_baseline) and self.max_baseline > 0):
            raise GsgsError(f"binocular: the baseline must be a positive distance (got {self.max_baseline})")

    def loss_terms(self, ctx: StepContext) -> dict | None:
        if ctx.step < self.start or (ctx.step - self.start) % self.every:
            return None
        tr = ctx.trainer
        u = torch.rand(2, generator=tr.torch_gen)
        baseline = float(u[0]) * self.max_baseline * (1.0 if float(u[1]) < 0.5 else -1.0)
        camera = ctx.camera if ctx.camera is not None else tr.train_views[ctx.view_index].camera
        depth, alpha, target = ctx.render.depth, ctx.render.alpha, ctx.target
        if self.bands > 1:  # one band of rows this step (class docstring)
            y0, y1 = band_rows(camera.height, self.bands, int(torch.randint(self.bands, (1,), generator=tr.torch_gen)))
            camera = band_camera(camera, y0, y1)
            depth, alpha, target = depth[y0:y1], alpha[y0:y1], target[y0:y1]
        shifted = shifted_camera(camera, baseline)
        if self.scale != 1.0:
            shifted = shifted.scaled(self.scale)
        out = tr.render_for_training(ctx, shifted, ctx.background, absgrad=False)
        z = surface_depth(depth, alpha)
        fused = binocular_l1(camera, z, shifted, out.color, target, alpha, MIN_OPAQUE)
        if fused is not None:  # the compiled warp + masked L1 (same value to float rounding; train/fused_binocular.py)
            l1, mask = fused
        else:
            warped, valid = warp_shifted_to_view(camera, z, shifted, out.color)
            mask = (valid & (alpha.detach() > MIN_OPAQUE)).detach()
            l1 = masked_l1(warped, target, mask)
        self.steps += 1
        self.last_valid = float(mask.float().mean())
        terms = {"binocular_l1": (self.weight, l1)}
        if self.smooth_weight > 0:
            disparity = camera.fx * abs(baseline) / z.clamp_min(1e-6)
            terms["binocular_smooth"] = (self.smooth_weight,
                                         edge_aware_smoothness(disparity * mask.to(disparity.dtype), target))
        return terms

    def state_dict(self) -> dict:
        return {"max_baseline": self.max_baseline, "scene_depth": self.scene_depth, "rig_baseline": self.rig_baseline,
                "steps": self.steps}

    def load_state_dict(self, state: dict) -> None:
        self.max_baseline = float(state["max_baseline"])
        self.scene_depth = state.get("scene_depth")
        self.rig_baseline = state.get("rig_baseline")
        self.steps = int(state.get("steps", 0))

    def report(self) -> dict:
        return {"weight": self.weight, "smooth_weight": self.smooth_weight, "max_baseline": self.max_baseline,
                "baseline_fraction": self.baseline_fraction, "scene_depth": self.scene_depth,
                "rig_baseline": self.rig_baseline, "rig_fraction": self.rig_fraction, "scale": self.scale,
                "every": self.every, "bands": self.bands,
                "start_step": self.start, "steps": self.steps, "last_valid_fraction": round(self.last_valid, 4)}
