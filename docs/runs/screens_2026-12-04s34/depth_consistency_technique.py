"""Free-space consistency of the rendered depth between the training views (issue 30, item 5).

Each training view's surface depth (its render's depth over its alpha, where the alpha says a surface
is there) is kept, detached, from its last training render. From `start_fraction` of the run on, a
step carries its training render's surface depth into the `neighbours` nearest training views that
have a kept depth (unproject, project): a surface point that the step's view places in front of what
the other view sees along the same ray, by more than `tolerance` of that depth, is a free-space
violation: the other photo looks through it. The term

    "depth_free_space" = mean over the neighbours of (1 / HW) sum_p relu((z_seen - z) / z_seen - tolerance)

(z the point's depth in the other camera, z_seen the other view's kept surface depth at its pixel,
nearest sample) pushes such points back along their own ray; points behind the other view's surface
(occluded there) and points the other view does not see cost nothing. Only the step's view takes the
gradient; the kept depths are a step or a few behind, as each view's depth is refreshed when it is
trained. No extra render: a few image-sized operations a neighbour.

Why: on LLFF flower the two test views between the training cameras have 37-40 % of their pixels in
no training photo under the model's own depth (their warp to every photo fails the 5 % depth check),
and those pixels carry 54-59 % of the views' error (docs/sparse_techniques.md, session 34), yet the
model's render there beats any fill from the other pixels: the photos do see most of it, at other
depths. The training views' depths disagree.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from gsgs_engine import GsgsError
from gsgs_engine.priors.warp import project, unproject
from gsgs_engine.train.technique import StepContext, Technique

DEFAULT_WEIGHT = 0.2
DEFAULT_TOLERANCE = 0.05  # relative depth: the warp-inpaint prior's visibility check
DEFAULT_START_FRACTION = 0.2
DEFAULT_NEIGHBOURS = 2
MIN_OPAQUE = 0.5  # a pixel takes part where the rendered alpha says a surface is there


def free_space_violation(camera, z: torch.Tensor, mask: torch.Tensor, other, other_z: torch.Tensor,
                         other_mask: torch.Tensor, tolerance: float) -> torch.Tensor:
    """(1 / HW) sum over `camera`'s pixels of relu((z_seen - z') / z_seen - tolerance), z' the depth in `other`
    of the pixel's surface point (depth `z`, where `mask`), z_seen `other`'s surface depth at its nearest pixel
    (where `other_mask`); 0 where the point is not in `other`'s image or is behind what it sees."""
    pts = unproject(camera, torch.where(mask, z, torch.ones_like(z)))
    uv, z_other = project(other, pts)
    h, w = other_z.shape
    grid = torch.stack([uv[..., 0] / w * 2 - 1, uv[..., 1] / h * 2 - 1], dim=-1)[None].detach()
    grid = torch.nan_to_num(grid, nan=-2.0, posinf=-2.0, neginf=-2.0)
    seen = torch.where(other_mask, other_z, torch.zeros_like(other_z))
    z_seen = F.grid_sample(seen[None, None], grid.to(seen.dtype), mode="nearest", padding_mode="zeros",
                           align_corners=False)[0, 0]
    valid = mask & (z_other > 1e-6) & (z_seen > 0) & (grid.abs() <= 1).all(dim=-1)[0]
    safe_seen = torch.where(valid, z_seen, torch.ones_like(z_seen))
    excess = torch.relu((safe_seen - z_other) / safe_seen - tolerance)
    return torch.where(valid, excess, torch.zeros_like(excess)).sum() / z.numel()


def nearest_views(centres: np.ndarray, k: int) -> list[list[int]]:
    """For each camera centre, the indices of its k nearest other centres, nearest first."""
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    d = np.linalg.norm(c[:, None] - c[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    return [[int(j) for j in np.argsort(row, kind="stable")[:min(k, len(c) - 1)]] for row in d]


class DepthConsistency(Technique):
    name = "depth_consistency"

    def __init__(self, weight: float = DEFAULT_WEIGHT, tolerance: float = DEFAULT_TOLERANCE,
                 start_fraction: float = DEFAULT_START_FRACTION, neighbours: int = DEFAULT_NEIGHBOURS):
        if not (np.isfinite(weight) and weight >= 0):
            raise GsgsError(f"depth_consistency: the weight must be >= 0 (got {weight})")
        if not (np.isfinite(tolerance) and 0 <= tolerance < 1):
            raise GsgsError(f"depth_consistency: the tolerance is a relative depth in [0, 1) (got {tolerance})")
        if not 0.0 <= start_fraction < 1.0:
            raise GsgsError(f"depth_consistency: start_fraction must be in [0, 1) (got {start_fraction})")
        if not (isinstance(neighbours, int) and neighbours >= 1):
            raise GsgsError(f"depth_consistency: neighbours must be a whole number >= 1 (got {neighbours!r})")
        self.weight, self.tolerance = float(weight), float(tolerance)
        self.start_fraction, self.neighbours = float(start_fraction), neighbours
        self.start = 1
        self.kept: dict[int, tuple] = {}  # view index -> (camera, surface depth, mask), detached
        self.near: list[list[int]] = []
        self.steps = 0
        self.last_value = 0.0
        self._device = "cpu"

    def install(self, trainer) -> None:
        self._device = trainer.device
        self.start = max(1, int(round(self.start_fraction * trainer.config.iters)) + 1)
        self.near = nearest_views([v.camera.center for v in trainer.train_views], self.neighbours)

    def loss_terms(self, ctx: StepContext) -> dict | None:
        tr = ctx.trainer
        camera = ctx.camera if ctx.camera is not None else tr.train_views[ctx.view_index].camera
        alpha = ctx.render.alpha
        mask = (alpha.detach() > MIN_OPAQUE)
        z = ctx.render.depth / alpha.detach().clamp_min(1e-6)
        terms = None
        if ctx.step >= self.start and self.weight > 0:
            others = [self.kept[j] for j in self.near[ctx.view_index] if j in self.kept]
            if others:
                value = sum(free_space_violation(camera, z, mask, cam, oz, om, self.tolerance)
                            for cam, oz, om in others) / len(others)
                self.steps += 1
                self.last_value = float(value.detach())
                terms = {"depth_free_space": (self.weight, value)}
        if ctx.step + 1 >= self.start:  # keep this view's depth for its neighbours' steps
            self.kept[ctx.view_index] = (camera, z.detach(), mask)
        return terms

    def state_dict(self) -> dict:
        kept = [[i, cam.to_dict(), z, mask] for i, (cam, z, mask) in sorted(self.kept.items())]
        return {"steps": self.steps, "last_value": self.last_value, "kept": kept}

    def load_state_dict(self, state: dict) -> None:
        from gsgs_engine.cameras import Camera

        self.steps = int(state.get("steps", 0))
        self.last_value = float(state.get("last_value", 0.0))
        self.kept = {int(i): (Camera.from_dict(cam, source="depth_consistency checkpoint"), z.to(self._device),
                              mask.to(self._device)) for i, cam, z, mask in state.get("kept", [])}

    def report(self) -> dict:
        return {"weight": self.weight, "tolerance": self.tolerance, "start_step": self.start,
                "neighbours": self.neighbours, "steps": self.steps, "last_value": round(self.last_value, 6)}
