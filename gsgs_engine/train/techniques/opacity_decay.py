"""Opacity decay without opacity reset (Binocular3DGS) as a training technique.

After a warm-up (the start of densification, as in Binocular3DGS) every step multiplies every
opacity by `factor` (0.995): o <- factor * o, done on the logits as
logit <- logit(factor * sigmoid(logit)). A Gaussian that the training views need is pushed back
up by the photometric gradient; one that only a single view half-supports (a floater) fades
below the opacity prune threshold and is removed at the next densification. It replaces 3DGS's
periodic opacity reset, so `install` changes the trainer's schedule:

- no periodic opacity reset (`opacity_reset_every` past the end of the run). The trainer's
  one-off reset of white-background scenes at the start of densification (3DGS's, step 17 of
  1000) stays by default: it comes before the first decayed step. `white_reset=0` drops it too
  (`Schedule.white_reset`); measured level without it on the forward-facing recipe (LLFF seeds 0-1,
  20.67 -> 20.68 dB; docs/sparse_techniques.md, "Session 45"), so no recipe drops it;
- densification runs to the end of training (`densify_until = iters`; its last event is one interval
  before the last step, never on it: Schedule.is_densify_step);
- the world-size prune: the trainer starts it after the first opacity reset, so with no reset
  it never runs. That is the intended choice, as in the Binocular3DGS code (its size threshold
  is None with decay): a large Gaussian the views do not support loses its opacity through the
  decay and is pruned by opacity, and on forward-facing scenes the world-size prune removes
  the large background Gaussians that a few views need (see trainer.size_extent).

Adam's moments of the opacities are left as they are (the decay is a parameter edit between
steps, like the paper's). The decay is deterministic, so resuming is bit-identical.

`presence=1` (4D models only; off by default): a Gaussian decays at the rate it is drawn. A step at
time t multiplies its peak opacity by factor ** w, with w = exp(-((t - mu_t) / s_t)^2) its temporal
opacity factor at t (`step_presence`). A static scene's Gaussian is in every training view, so one
decay a step meets one photometric push back a step; a Gaussian of a video is in the views of a few
frames only, and by default it is decayed at every step of the clip: about three times the static
rate for the recipe's per-frame Gaussians (temporal scale two frames of ten: the factor below sums to
about 3.5 over the ten frames). Measured on the
Panoptic capture over three seeds (docs/dynamic_panoptic.md, session 13): +0.33 dB for the 4D model
with 6 cameras, -0.27 dB with 3, so it stays a setting. A 3D model is decayed as before, to the bit.
"""

from __future__ import annotations

import math

import torch

from gsgs_engine import GsgsError
from gsgs_engine.train.technique import Technique

DEFAULT_FACTOR = 0.995  # Binocular3DGS; 0.990-0.998 all work there


def decay_opacity_logits(logits: torch.Tensor, factor: float) -> torch.Tensor:
    """logit(factor * sigmoid(logits)), computed stably: log(f s / (1 - f s)) with s = sigmoid(x); `factor` a
    float in (0, 1) or a tensor of such factors, one per logit.

    For x >> 0, 1 - f s -> 1 - f (finite); for x << 0, f s -> f e^x and the result -> x + log f.
    """
    # log(f s) = log f + logsigmoid(x); log(1 - f s) = log1p(-f * sigmoid(x)) (f < 1 keeps it finite)
    f = torch.as_tensor(factor, dtype=logits.dtype, device=logits.device)  # a float, or one per Gaussian
    log_fs = torch.log(f) + torch.nn.functional.logsigmoid(logits)
    log_one_minus = torch.log1p(-factor * torch.sigmoid(logits))
    return log_fs - log_one_minus


def step_presence(trainer) -> torch.Tensor | None:
    """Each Gaussian's temporal opacity factor at the time of the step's training view, for a 4D model (the
    trainer's `last_step_renders` name the view); None for a 3D model or a view without a time."""
    from gsgs_engine.spacetime import SpacetimeModel, temporal_weight

    model = trainer.model
    renders = getattr(trainer, "last_step_renders", None)
    if not isinstance(model, SpacetimeModel) or not renders or renders[0][1].time is None:
        return None
    return temporal_weight(model.t_center, model.t_scale, float(renders[0][1].time))


class OpacityDecay(Technique):
    name = "opacity_decay"

    def __init__(self, factor: float = DEFAULT_FACTOR, start: int | None = None, presence: int = 0,
                 white_reset: int = 1):
        if not 0.0 < factor < 1.0:
            raise GsgsError(f"opacity_decay: the factor must be in (0, 1) (got {factor})")
        if presence not in (0, 1):  # bool is an int: True / False pass too
            raise GsgsError(f"opacity_decay: presence is 0 or 1 (got {presence!r}; e.g. opacity_decay:presence=1)")
        if white_reset not in (0, 1):
            raise GsgsError(f"opacity_decay: white_reset is 0 or 1 (got {white_reset!r}; e.g. opacity_decay:white_reset=0)")
        self.factor = float(factor)
        self.presence = bool(presence)
        self.white_reset = bool(white_reset)
        self.start = start  # first decayed step (None: the schedule's densify_from)
        self.steps_decayed = 0

    def install(self, trainer) -> None:
        sched = trainer.schedule
        if self.start is None:
            self.start = int(sched.densify_from) + 1
        sched.densify_until = int(sched.iters)
        # is_opacity_reset_step(step) needs step % every == 0 for some step <= iters: never with every > iters.
        sched.opacity_reset_every = int(sched.iters) + 1
        sched.white_reset = self.white_reset

    def after_step(self, trainer, step: int) -> None:
        if step < self.start:
            return
        with torch.no_grad():
            logits = trainer.model.params["opacity_logits"]
            presence = step_presence(trainer) if self.presence else None
            factor = self.factor if presence is None else torch.exp(presence * math.log(self.factor))
            logits.copy_(decay_opacity_logits(logits, factor))
        self.steps_decayed += 1

    def state_dict(self) -> dict:
        return {"steps_decayed": self.steps_decayed, "start": self.start}

    def load_state_dict(self, state: dict) -> None:
        self.steps_decayed = int(state.get("steps_decayed", 0))
        if state.get("start") is not None:
            self.start = int(state["start"])

    def report(self) -> dict:
        return {"factor": self.factor, "start_step": self.start, "steps_decayed": self.steps_decayed,
                "presence": ("4D: factor ** (temporal opacity factor at the step's time) per Gaussian" if self.presence
                             else "off: every Gaussian by the factor each step"),
                "opacity_reset": "off (periodic); " + ("white-background scenes keep the one at the start of "
                                                       "densification" if self.white_reset else "and off at the "
                                                       "start of densification (white_reset=0)"),
                "densify_until": "end of training",
                "world_size_prune": "off (the trainer starts it after the first reset; decay prunes by opacity)"}
