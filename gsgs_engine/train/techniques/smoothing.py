"""Mip-Splatting's 3D smoothing filter as a training technique.

A Gaussian finer than the training photos sample it is not constrained by them: sparse views leave
such needles and sheets free to alias in a novel view. Mip-Splatting (Yu et al., CVPR 2024, eq. 7)
convolves every Gaussian with an isotropic 3D Gaussian the size of its finest training pixel: the
covariance R S^2 R^T becomes R S^2 R^T + s2 I, with s2 = FILTER_VARIANCE * (z / f)^2, where z / f is
the Gaussian's world-space pixel footprint (its depth over the focal length in pixels) in the
training camera that samples it most finely. An isotropic term commutes with the rotation, so the
filtered Gaussian keeps its rotation and its scales become sqrt(s^2 + s2) (`smoothed`);
its opacity is scaled by sqrt(det(S^2) / det(S^2 + s2 I)) = prod(s / sqrt(s^2 + s2)) so that its
integral, and so its contribution to a pixel much larger than it, stays the same.

Every supervised render sees the filtered model (`render_inputs`). The footprints are recomputed
from the current centres every `REFRESH` steps and whenever the Gaussian count changes. At the last
step the filter is baked into the model's parameters (log-scales and opacity logits, with footprints
recomputed from the final centres), so the saved model, evaluation renders, the PLY and Blender show
the filtered Gaussians training optimised; a run that trains past
that point (a resumed longer schedule) renders without the filter again.
"""

from __future__ import annotations

import torch

from gsgs_engine import GsgsError
from gsgs_engine.train.technique import StepContext, Technique

FILTER_VARIANCE = 0.2  # Mip-Splatting's 3D filter variance, in training pixels^2
FRUSTUM_MARGIN = 0.15  # a camera counts for a centre up to 15 % of its image beyond each edge (Mip-Splatting)
REFRESH = 100  # steps between recomputations of the footprints (densification's interval in Mip-Splatting)


def pixel_footprints(means: torch.Tensor, cameras) -> torch.Tensor:
    """Each centre's finest world-space pixel size over `cameras`: min of z / max(fx, fy) over the cameras it lies
    in front of and inside (the image widened by FRUSTUM_MARGIN); [N], float32 on the CPU.

    A centre no camera sees (a non-finite centre too) gets the largest footprint of the others; with no centre seen
    at all the result is 0 everywhere: no filter."""
    x = means.detach().to("cpu", torch.float32)
    best = torch.full((x.shape[0],), float("inf"))
    for cam in cameras:
        R = torch.as_tensor(cam.R, dtype=torch.float32)
        t = torch.as_tensor(cam.t, dtype=torch.float32)
        p = x @ R.T + t
        z = p[:, 2]
        front = z > 0
        zs = torch.where(front, z, torch.ones_like(z))
        u = cam.fx * p[:, 0] / zs + cam.cx
        v = cam.fy * p[:, 1] / zs + cam.cy
        mw, mh = FRUSTUM_MARGIN * cam.width, FRUSTUM_MARGIN * cam.height
        inside = front & (u >= -mw) & (u <= cam.width + mw) & (v >= -mh) & (v <= cam.height + mh)
        footprint = z / max(float(cam.fx), float(cam.fy))
        best = torch.where(inside & torch.isfinite(footprint), torch.minimum(best, footprint), best)
    seen = torch.isfinite(best)
    if not bool(seen.any()):
        return torch.zeros_like(best)
    return torch.where(seen, best, best[seen].max())


def smoothed(scales: torch.Tensor, opacities: torch.Tensor, variance: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(scales', opacities') of the Gaussians convolved with an isotropic 3D Gaussian of `variance` [N] (eq. 7):
    scales' = sqrt(scales^2 + variance), opacities' = opacities * prod(scales / scales'). Differentiable; finite
    for scales that underflow to 0 as long as the variance is positive (then the opacity goes to 0)."""
    v = variance.to(scales.device, scales.dtype).reshape(-1, 1)
    filtered = torch.sqrt(scales * scales + v)
    ratio = torch.where(v > 0, scales / torch.where(v > 0, filtered, torch.ones_like(filtered)), torch.ones_like(scales))
    factor = ratio.prod(dim=1)
    return filtered, opacities * factor.reshape(-1, *([1] * (opacities.ndim - 1)))


class SmoothingFilter(Technique):
    name = "smoothing"

    def __init__(self, variance: float = FILTER_VARIANCE):
        if not variance > 0:
            raise GsgsError(f"smoothing: the variance must be positive, in training pixels^2 (got {variance})")
        self.variance = float(variance)
        self._filter: torch.Tensor | None = None  # [N] world-space variance
        self._computed_at = -1
        self.baked_at: int | None = None
        self.refreshes = 0

    def install(self, trainer) -> None:
        self._cameras = [v.camera for v in trainer.train_views]

    def filter_variance(self, trainer, step: int) -> torch.Tensor:
        n = trainer.model.num_gaussians
        if self._filter is None or self._filter.shape[0] != n or step - self._computed_at >= REFRESH:
            footprint = pixel_footprints(trainer.model.means, self._cameras)
            self._filter = self.variance * footprint * footprint
            self._computed_at = step
            self.refreshes += 1
        return self._filter

    def render_inputs(self, ctx: StepContext, inputs: dict) -> dict:
        if self.baked_at is not None:
            return inputs
        variance = self.filter_variance(ctx.trainer, ctx.step)
        scales, opacities = smoothed(inputs["scales"], inputs["opacities"], variance)
        return {**inputs, "scales": scales, "opacities": opacities}

    def after_step(self, trainer, step: int) -> None:
        if self.baked_at is None and step >= trainer.config.iters:
            self.bake(trainer, step)

    def bake(self, trainer, step: int) -> None:
        """Write the filtered scales and opacities into the model's parameters (no filter after this)."""
        model = trainer.model
        variance = pixel_footprints(model.means, self._cameras)
        variance = self.variance * variance * variance
        with torch.no_grad():
            scales, opacities = smoothed(model.scales, model.opacities, variance)
            model.params["log_scales"].copy_(torch.log(scales))
            o = opacities.clamp(1e-7, 1 - 1e-7)
            model.params["opacity_logits"].copy_(torch.log(o) - torch.log1p(-o))
        self.baked_at = step

    def state_dict(self) -> dict:
        # the footprints too: recomputed on resume from moved centres they would differ from the straight run's
        return {"baked_at": self.baked_at, "computed_at": self._computed_at, "refreshes": self.refreshes,
                "filter": None if self._filter is None else self._filter.detach().cpu().clone()}

    def load_state_dict(self, state: dict) -> None:
        self.baked_at = state.get("baked_at")
        self._computed_at = int(state.get("computed_at", -1))
        self.refreshes = int(state.get("refreshes", 0))
        self._filter = state.get("filter")

    def report(self) -> dict:
        return {"variance_pixels2": self.variance, "refresh_steps": REFRESH, "refreshes": self.refreshes,
                "baked_at_step": self.baked_at}
