"""Progressive Gaussian dropout (DropGaussian) as a training technique.

Every training render (the training view and any view a technique supervises through
`Trainer.render_for_training`) sees each Gaussian's opacity multiplied by a random keep mask
scaled by 1 / (1 - p), so the expected opacity is unchanged; p ramps linearly from 0 at the
first step to `max_rate` at the last. Gaussians that a few others hide get gradients, and no
single Gaussian can carry a training pixel alone. Evaluation renders (`Trainer.render`) use
every Gaussian at its own opacity.

The mask is drawn from the trainer's seeded CPU generator (`trainer.torch_gen`), which the
trainer checkpoints: a run is deterministic and resumes bit-identically.
"""

from __future__ import annotations

import torch

from gsgs_engine import GsgsError
from gsgs_engine.train.technique import StepContext, Technique

DEFAULT_MAX_RATE = 0.2  # DropGaussian's final drop rate


def drop_rate(step: int, iters: int, max_rate: float = DEFAULT_MAX_RATE) -> float:
    """p at 1-based `step` of `iters`: linear from 0 to `max_rate` over training."""
    return float(max_rate) * min(max(step / max(iters, 1), 0.0), 1.0)


def dropout_opacities(opacities: torch.Tensor, rate: float, generator: torch.Generator) -> torch.Tensor:
    """opacities * keep / (1 - rate), keep ~ Bernoulli(1 - rate) per Gaussian (unbiased in expectation)."""
    if rate <= 0.0:
        return opacities
    keep = (torch.rand(opacities.shape[0], generator=generator) >= rate).to(opacities.device, opacities.dtype)
    return opacities * keep.reshape(-1, *([1] * (opacities.ndim - 1))) / (1.0 - rate)


class GaussianDropout(Technique):
    name = "dropout"

    def __init__(self, max_rate: float = DEFAULT_MAX_RATE):
        if not 0.0 <= max_rate < 1.0:
            raise GsgsError(f"dropout: the final drop rate must be in [0, 1) (got {max_rate})")
        self.max_rate = float(max_rate)
        self.trainer = None
        self.renders_dropped = 0
        self.last_rate = 0.0

    def install(self, trainer) -> None:
        self.trainer = trainer

    def render_inputs(self, ctx: StepContext, inputs: dict) -> dict:
        tr = ctx.trainer
        rate = drop_rate(ctx.step, tr.config.iters, self.max_rate)
        self.last_rate = rate
        if rate <= 0.0:
            return inputs
        self.renders_dropped += 1
        return {**inputs, "opacities": dropout_opacities(inputs["opacities"], rate, tr.torch_gen)}

    def state_dict(self) -> dict:
        return {"renders_dropped": self.renders_dropped, "last_rate": self.last_rate}

    def load_state_dict(self, state: dict) -> None:
        self.renders_dropped = int(state.get("renders_dropped", 0))
        self.last_rate = float(state.get("last_rate", 0.0))

    def report(self) -> dict:
        return {"max_rate": self.max_rate, "schedule": "linear 0 -> max_rate over the run, training renders only",
                "renders_dropped": self.renders_dropped, "final_rate": round(self.last_rate, 4)}
