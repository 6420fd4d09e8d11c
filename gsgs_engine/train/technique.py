"""How a sparse-view technique takes part in training, without the trainer naming it.

The trainer (train/trainer.py) runs the optimisation: steps, the photometric loss of the
training view, densification, checkpoints. Everything else — pseudo views, the GS-GS prior
loop, the depth regulariser, dropout, opacity decay, co-regularisation — is a `Technique`
added with `Trainer.add_technique`. The idea is gsplat's `Strategy`: a small set of hooks at
fixed points of a step, state the technique checkpoints itself, and a report for
metrics.json. Hooks run in the order the techniques were added.

A step, with the hooks marked:

    before_step(trainer, step)                      # e.g. change opacities, pick a camera
    render the training view (render_inputs(ctx, inputs) may rewrite the rasteriser's inputs)
    photometric terms of the training view
    loss_terms(ctx) -> {name: (weight, tensor)}    # e.g. a pseudo view's terms, eq. 10
    backward, densification statistics of every render in ctx.renders, optimiser step,
    densify / prune / opacity reset
    after_step(trainer, step)                       # e.g. regenerate pseudo views, prune, add Gaussians

A technique that adds Gaussians or removes them must keep the optimiser and the densification
statistics in step (gsgs_engine.train.densify.append_gaussians / DensifyStats.grow do both).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


#: ctx.shared key: the training view whose photo supervises the render being made, where it is not the step's
#: own view (a pseudo view warped from that photo); per-camera corrections (techniques/exposure.py) read it
PHOTO_VIEW = "photo_view"


def joined_sh(inputs: dict) -> dict:
    """Rasteriser inputs with the SH coefficients in one tensor `sh` [N, (degree + 1)^2, 3].

    The trainer passes the model's DC term as `sh` and its higher bands as `sh_rest` (render() reads the two
    where they are); a technique that rewrites the coefficients takes them joined from here, exactly the tensor
    GaussianModel.sh() makes, and returns them without `sh_rest`."""
    rest = inputs.get("sh_rest")
    if rest is None:
        return inputs
    import torch

    from gsgs_engine.render.sh import num_sh_bases

    sh = inputs["sh"]
    wanted = max(num_sh_bases(int(inputs["sh_degree"])) - sh.shape[1], 0)
    return {**inputs, "sh": torch.cat([sh, rest[:, :wanted]], dim=1), "sh_rest": None}


@dataclass
class StepContext:
    """What a technique's hooks may look at in the current step.

    `renders` holds (render output, camera) of every render whose screen-space gradient feeds
    densification this step; a technique that renders another view for its loss appends it.
    `shared` passes values between techniques within the step (e.g. the pseudo view that was
    rendered, for the depth regulariser).
    """

    trainer: Any
    step: int
    view_index: int
    render: Any  # RenderOutput of the training view
    target: Any
    background: Any
    renders: list = field(default_factory=list)
    shared: dict = field(default_factory=dict)
    camera: Any = None  # the camera `render` was made with (the training view's, at this step's resolution)


class Technique:
    """Base class: every hook does nothing. Override the ones the technique needs."""

    #: the key under which metrics.json["techniques"] and the checkpoint hold this technique
    name: str = "technique"

    def install(self, trainer) -> None:
        """Called once, after the trainer's model exists (new or restored from a checkpoint)."""

    def before_step(self, trainer, step: int) -> None:
        """Before the step's renders; `step` is the 1-based step about to run."""

    def render_inputs(self, ctx: StepContext, inputs: dict) -> dict:
        """Rewrite the rasteriser's inputs (means, quats, scales, opacities, sh, sh_rest, sh_degree) of a training
        render; must stay differentiable. Called for every render made through
        `Trainer.render_for_training` (training views and a technique's own supervised views). The SH
        coefficients may come in two parts (`sh` the DC term, `sh_rest` the rest): rewrite them through
        `joined_sh(inputs)`."""
        return inputs

    def loss_terms(self, ctx: StepContext) -> dict | None:
        """Extra terms of this step's loss: {name: tensor} or {name: (weight, tensor)}."""
        return None

    def after_step(self, trainer, step: int) -> None:
        """After the optimiser step and the trainer's densification of `step`."""

    def state_dict(self) -> dict:
        """What a checkpoint keeps of this technique (tensors on the CPU, JSON-like values)."""
        return {}

    def load_state_dict(self, state: dict) -> None:
        """Restore what `state_dict` returned (called after `install` when resuming)."""

    def report(self) -> dict:
        """What metrics.json records about this technique (its settings and what it did)."""
        return {}
