"""Depth distortion: one surface along each ray of a training view (Mip-NeRF 360's distortion loss, 2DGS).

Three photos can be explained by layers: a semi-transparent copy of a surface at one depth for one photo, another
at another depth for the next. Every training view looks right; a view between them sees the copies apart (the
doubled, smeared edges of the forward-facing test views between the cameras, docs/sparse_techniques.md, sessions 16
and 34). Mip-NeRF 360 charges a ray for the spread of its weights along depth, sum_ij w_i w_j |s_i - s_j|; 2DGS
carries it to splats. Here the squared form, which the rasteriser's compositing gives without a new kernel:

    A = sum_i w_i,  S1 = sum_i w_i s_i,  S2 = sum_i w_i s_i^2    (w_i = alpha_i T_i, blending weights)
    spread = S2 / A - (S1 / A)^2 = sum_i (w_i / A) (s_i - mean s)^2

the variance of the ray's depth under its normalised blend weights (`ray_depth_spread`): zero when one surface
takes the ray, whatever its opacity, so the term cannot be lowered by making a surface transparent (the free-space
term of session 34 could). s is the depth as a disparity relative to the scene, s = z_ref / z (z_ref: the 5th
percentile of the initial Gaussians' distance to their nearest training camera, measured at install), capped at
MAX_DISPARITY: bounded, scale-free, and a far background's layers count less than a near subject's, as parallax
does. The term is the spread's mean over the pixels a surface covers (rendered alpha above `min_alpha`).

A step renders (S1, S2) as the colour of a second composite of the training view's Gaussians (the techniques'
`render_inputs` applied, as the training render), at `scale` of its size (the blending weights of a half-size view
are the full view's, sampled coarser, for a quarter of the pixels), from `start_fraction` of the run, every `every`
steps. Not added to the densification statistics. The compiled CPU rasteriser, the reference or CUDA (gsplat
composites any colour).
"""

from __future__ import annotations

import numpy as np
import torch

from gsgs_engine import GsgsError
from gsgs_engine.train.technique import StepContext, Technique
from gsgs_engine.train.techniques.binocular import nearest_camera_distances

# The orbit recipe's (docs/sparse_techniques.md, "Session 47"): weight 6 every 8th step gains what weight 1 at every
# step gained (NeRF-synthetic 8 views, seeds 0-2: 27.26 -> 27.40 dB either way; every 4th step at weight 3: 27.39)
# for an eighth of its renders (weight 0.75 a step on average, against 1).
DEFAULT_WEIGHT = 6.0
DEFAULT_EVERY = 8
DEFAULT_START_FRACTION = 0.2
DEFAULT_SCALE = 0.5
DEFAULT_MIN_ALPHA = 0.5
REFERENCE_PERCENTILE = 5.0
MAX_DISPARITY = 2.0  # s saturates for a Gaussian nearer than half the reference depth


def ray_depth_spread(alpha: torch.Tensor, s1: torch.Tensor, s2: torch.Tensor) -> torch.Tensor:
    """Variance of the depth along each ray under its normalised blend weights: S2 / A - (S1 / A)^2, >= 0."""
    a = alpha.clamp_min(1e-6)
    mean = s1 / a
    return (s2 / a - mean * mean).clamp_min(0.0)


def reference_depth(points, camera_centers, percentile: float = REFERENCE_PERCENTILE) -> float:
    """The `percentile` of the points' distance to their nearest camera centre (finite points; <= 20k sampled)."""
    return float(np.percentile(nearest_camera_distances(points, camera_centers, "distortion"), percentile))


def moment_colors(z: torch.Tensor, z_ref: float) -> torch.Tensor:
    """Per-Gaussian "colours" (s, s^2, 0) of s = z_ref / z, capped at MAX_DISPARITY: their composite is (S1, S2)."""
    s = (z_ref / z.clamp_min(1e-6)).clamp(max=MAX_DISPARITY)
    return torch.stack([s, s * s, torch.zeros_like(s)], dim=-1)


def composite_moments(inputs: dict, camera, z_ref: float, backend: str):
    """(alpha, S1, S2) of `camera` [H, W] each: the blend weights' sum and first two moments of s = z_ref / z."""
    from gsgs_engine.render.api import DEFAULT_NEAR, rasterize, select_backend

    means, quats, scales, opacities = inputs["means"], inputs["quats"], inputs["scales"], inputs["opacities"]
    if opacities.dim() == 2:
        opacities = opacities[:, 0]
    sh_dc = inputs["sh"][:, :1]
    black = torch.zeros(3, dtype=means.dtype, device=means.device)
    chosen = select_backend(backend, means.device, means.dtype)
    if chosen == "cuda":  # gsplat projects and composites in one call: z from the camera transform
        from gsgs_engine.render import cuda_backend

        R = torch.as_tensor(camera.R, dtype=means.dtype, device=means.device)
        z = means @ R[2] + float(camera.t[2])
        color, _, alpha, _, _ = cuda_backend.render_gsplat(means, quats, scales, opacities, moment_colors(z, z_ref),
                                                           camera, black, DEFAULT_NEAR, 1e10)
        return alpha, color[..., 0], color[..., 1]
    if chosen == "cpu":
        from gsgs_engine.render.project_cpu import project_gaussians_cpu
        proj = project_gaussians_cpu(means, quats, scales, camera, sh_dc, sh_degree=0)
    else:
        from gsgs_engine.render.project import project_gaussians
        proj = project_gaussians(means, quats, scales, camera, sh=sh_dc, sh_degree=0)
    color, _, alpha = rasterize(proj.means2d, proj.conics, moment_colors(proj.depths, z_ref), opacities, proj.depths,
                                proj.radii, camera.width, camera.height, black, backend=chosen)
    return alpha, color[..., 0], color[..., 1]


class DepthDistortion(Technique):
    name = "distortion"

    def __init__(self, weight: float = DEFAULT_WEIGHT, start_fraction: float = DEFAULT_START_FRACTION,
                 scale: float = DEFAULT_SCALE, every: int = DEFAULT_EVERY, min_alpha: float = DEFAULT_MIN_ALPHA):
        if weight < 0:
            raise GsgsError(f"distortion: weight must be >= 0 (got {weight})")
        if not 0.0 <= start_fraction < 1.0:
            raise GsgsError(f"distortion: start_fraction must be in [0, 1) (got {start_fraction})")
        if not 0.0 < scale <= 1.0:
            raise GsgsError(f"distortion: the render scale must be in (0, 1] (got {scale})")
        if not (isinstance(every, int) and every >= 1):
            raise GsgsError(f"distortion: every must be a whole number of steps >= 1 (got {every!r})")
        if not 0.0 <= min_alpha < 1.0:
            raise GsgsError(f"distortion: min_alpha must be in [0, 1) (got {min_alpha})")
        self.weight, self.start_fraction, self.scale = float(weight), float(start_fraction), float(scale)
        self.every, self.min_alpha = every, float(min_alpha)
        self.z_ref: float | None = None
        self.start = 1
        self.steps = 0
        self.last_spread = 0.0

    def install(self, trainer) -> None:
        self.start = max(1, int(round(self.start_fraction * trainer.config.iters)) + 1)
        if self.z_ref is None:
            centres = [v.camera.center for v in trainer.train_views]
            self.z_ref = reference_depth(trainer.model.means.detach().cpu().numpy(), centres)
        if not (np.isfinite(self.z_ref) and self.z_ref > 0):
            raise GsgsError(f"distortion: the reference depth must be a positive distance (got {self.z_ref})")

    def loss_terms(self, ctx: StepContext) -> dict | None:
        if self.weight == 0 or ctx.step < self.start or (ctx.step - self.start) % self.every:
            return None
        tr = ctx.trainer
        camera = ctx.camera if ctx.camera is not None else tr.train_views[ctx.view_index].camera
        if self.scale != 1.0:
            camera = camera.scaled(self.scale)
        alpha, s1, s2 = composite_moments(tr.training_inputs(ctx, camera), camera, self.z_ref, tr.config.backend)
        mask = (alpha.detach() > self.min_alpha).to(alpha.dtype)
        spread = (ray_depth_spread(alpha, s1, s2) * mask).sum() / mask.sum().clamp_min(1.0)
        self.steps += 1
        self.last_spread = float(spread.detach())
        return {"distortion": (self.weight, spread)}

    def state_dict(self) -> dict:
        return {"z_ref": self.z_ref, "steps": self.steps}

    def load_state_dict(self, state: dict) -> None:
        self.z_ref = state.get("z_ref")
        self.steps = int(state.get("steps", 0))

    def report(self) -> dict:
        return {"weight": self.weight, "start_step": self.start, "scale": self.scale, "every": self.every,
                "min_alpha": self.min_alpha, "z_ref": self.z_ref, "steps": self.steps,
                "last_spread": round(self.last_spread, 6)}
