"""Opacity decay without opacity reset (Binocular3DGS) as a training technique.

After a warm-up (the start of densification, as in Binocular3DGS) every step multiplies every
opacity by `factor` (0.995): o <- factor * o, done on the logits as
logit <- logit(factor * sigmoid(logit)). A Gaussian that the training views need is pushed back
up by the photometric gradient; one that only a single view half-supports (a floater) fades
below the opacity prune threshold and is removed at the next densification. It replaces 3DGS's
periodic opacity reset, so `install` changes the trainer's schedule:

- no periodic opacity reset (`opacity_reset_every` past the end of the run). The trainer's
  one-off reset of white-background scenes at the start of densification (3DGS's, step 17 of
  1000) stays: it comes before the first decayed step, and the schedule has no switch for it
  that would not also move the start of densification;
- densification runs to the end of training (`densify_until = iters`);
- the world-size prune: the trainer starts it after the first opacity reset, so with no reset
  it never runs. That is the intended choice, as in the Binocular3DGS code (its size threshold
  is None with decay): a large Gaussian the views do not support loses its opacity through the
  decay and is pruned by opacity, and on forward-facing scenes the world-size prune removes
  the large background Gaussians that a few views need (see trainer.size_extent).

Adam's moments of the opacities are left as they are (the decay is a parameter edit between
steps, like the paper's). The decay is deterministic, so resuming is bit-identical.
"""

from __future__ import annotations

import torch

from gsgs_engine import GsgsError
from gsgs_engine.train.technique import Technique

DEFAULT_FACTOR = 0.995  # Binocular3DGS; 0.990-0.998 all work there


def decay_opacity_logits(logits: torch.Tensor, factor: float) -> torch.Tensor:
    """logit(factor * sigmoid(logits)), computed stably: log(f s / (1 - f s)) with s = sigmoid(x).

    For x >> 0, 1 - f s -> 1 - f (finite); for x << 0, f s -> f e^x and the result -> x + log f.
    """
    # log(f s) = log f + logsigmoid(x); log(1 - f s) = log1p(-f * sigmoid(x)) (f < 1 keeps it finite)
    log_fs = torch.log(torch.tensor(factor, dtype=logits.dtype, device=logits.device)) + torch.nn.functional.logsigmoid(logits)
    log_one_minus = torch.log1p(-factor * torch.sigmoid(logits))
    return log_fs - log_one_minus


class OpacityDecay(Technique):
    name = "opacity_decay"

    def __init__(self, factor: float = DEFAULT_FACTOR, start: int | None = None):
        if not 0.0 < factor < 1.0:
            raise GsgsError(f"opacity_decay: the factor must be in (0, 1) (got {factor})")
        self.factor = float(factor)
        self.start = start  # first decayed step (None: the schedule's densify_from)
        self.steps_decayed = 0

    def install(self, trainer) -> None:
        sched = trainer.schedule
        if self.start is None:
            self.start = int(sched.densify_from) + 1
        sched.densify_until = int(sched.iters)
        # is_opacity_reset_step(step) needs step % every == 0 for some step <= iters: never with every > iters.
        sched.opacity_reset_every = int(sched.iters) + 1

    def after_step(self, trainer, step: int) -> None:
        if step < self.start:
            return
        with torch.no_grad():
            logits = trainer.model.params["opacity_logits"]
            logits.copy_(decay_opacity_logits(logits, self.factor))
        self.steps_decayed += 1

    def state_dict(self) -> dict:
        return {"steps_decayed": self.steps_decayed, "start": self.start}

    def load_state_dict(self, state: dict) -> None:
        self.steps_decayed = int(state.get("steps_decayed", 0))
        if state.get("start") is not None:
            self.start = int(state["start"])

    def report(self) -> dict:
        return {"factor": self.factor, "start_step": self.start, "steps_decayed": self.steps_decayed,
                "opacity_reset": "off (periodic); white-background scenes keep the one at the start of densification", "densify_until": "end of training",
                "world_size_prune": "off (the trainer starts it after the first reset; decay prunes by opacity)"}
