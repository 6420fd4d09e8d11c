"""Needle penalty (screen): Gaussians whose largest axis is more than `ratio` times the middle one pay
mean(relu(s_max / s_mid - ratio)) x weight. Disks (two large axes, one small) are free; needles, which streak at
novel views, are not. PhysGaussian penalises max / min; that would also flatten-penalise surface disks."""

from __future__ import annotations

import torch

from gsgs_engine import GsgsError
from gsgs_engine.train.technique import StepContext, Technique


class NeedlePenalty(Technique):
    name = "needle"

    def __init__(self, weight: float = 0.1, ratio: float = 5.0, every: int = 1):
        if weight < 0 or ratio <= 1:
            raise GsgsError(f"needle: weight >= 0 and ratio > 1 (got {weight}, {ratio})")
        self.weight, self.ratio, self.every = float(weight), float(ratio), int(every)
        self.last_fraction = 0.0

    def loss_terms(self, ctx: StepContext) -> dict | None:
        if self.weight == 0 or ctx.step % self.every:
            return None
        ls = ctx.trainer.model.params["log_scales"]
        top2 = torch.topk(ls, 2, dim=1).values
        r = torch.exp(top2[:, 0] - top2[:, 1])
        over = torch.relu(r - self.ratio)
        self.last_fraction = float((over.detach() > 0).float().mean())
        return {"needle": (self.weight, over.mean())}

    def report(self) -> dict:
        return {"weight": self.weight, "ratio": self.ratio, "last_fraction_over": round(self.last_fraction, 4)}
