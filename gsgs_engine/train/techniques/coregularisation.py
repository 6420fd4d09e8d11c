"""Co-regularisation of two Gaussian fields (CoR-GS), as a training technique.

A second field (the partner) trains side by side with the main one, from the same initial
Gaussians but its own random stream (view order, backgrounds, densification). Two things tie
them together:

- co-regularisation: each step after a warm-up, both fields render one random pseudo view
  (interpolated between neighbouring training cameras) and each is pulled towards the other's
  render (L1 + D-SSIM, the other side detached); where the training views leave the scene
  unconstrained the two fields disagree, and agreement removes what only one of them invented;
- co-pruning: every `prune_every` steps while densification runs, Gaussians of either field with
  no Gaussian of the other field near them are removed.

The partner trains with the same other techniques as the main field (fresh instances of the same
names and options, `partner_techniques`, set by the catalogue): a budgeted, dropout-regularised
main field co-regularised with a plain partner would be pulled towards plain 3DGS's floaters. Only
the main field has the prior loop's pseudo views (techniques/prior_loop.py is added after every
technique). Only the main field is exported. The partner doubles the cost of a step (measured in
docs/sparse_techniques.md); its state (its techniques' included) is checkpointed in
CHECKPOINTS/coregularisation/, so a resumed run continues both fields.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch

from gsgs_engine import GsgsError
from gsgs_engine.train.densify import keep_gaussians
from gsgs_engine.train.losses import photometric_terms
from gsgs_engine.train.technique import StepContext, Technique

PSEUDO_POOL = 64  # pseudo cameras to draw from (CoR-GS samples new interpolated poses; a fixed pool is reproducible)


def isolated(points: torch.Tensor, others: torch.Tensor, radius: float) -> torch.Tensor:
    """Mask of `points` with no point of `others` within `radius` (co-pruning's test).

    Both sets are hashed into cubic cells of side `radius`; a point is isolated when none of the
    27 cells around it holds a point of `others`. Every neighbour within `radius` lies in those
    cells, so an isolated point truly has none; a point whose nearest other lies between `radius`
    and 2*sqrt(3)*`radius` may be kept (the test errs towards keeping).
    """
    if points.shape[0] == 0:
        return torch.zeros(0, dtype=torch.bool)
    if others.shape[0] == 0:
        return torch.ones(points.shape[0], dtype=torch.bool)
    if not (np.isfinite(radius) and radius > 0):
        raise GsgsError(f"co-pruning radius must be a positive number, got {radius}")
    p = points.detach().cpu().double().numpy()
    o = others.detach().cpu().double().numpy()
    lo = np.minimum(p.min(0), o.min(0)) - radius
    cell_p = np.floor((p - lo) / radius).astype(np.int64) + 1
    cell_o = np.floor((o - lo) / radius).astype(np.int64) + 1
    dims = np.maximum(cell_p.max(0), cell_o.max(0)) + 2
    if float(np.prod(dims.astype(np.float64))) > 2.0 ** 62:
        raise GsgsError(f"co-pruning radius {radius:g} is too small for the scene's extent")

    def key(c: np.ndarray) -> np.ndarray:
        return (c[:, 0] * dims[1] + c[:, 1]) * dims[2] + c[:, 2]

    occupied = np.unique(key(cell_o))
    near = np.zeros(len(p), dtype=bool)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                near |= np.isin(key(cell_p + np.array([dx, dy, dz])), occupied, assume_unique=False)
    return torch.from_numpy(~near)


def prune_isolated(trainer, others: torch.Tensor, radius: float) -> int:
    """Remove the trainer's Gaussians that `isolated` finds (never all of them); returns how many."""
    mask = isolated(trainer.model.means, others, radius).to(trainer.model.means.device)
    if bool(mask.all()):
        mask[torch.argmax(trainer.model.opacities.detach())] = False
    n = int(mask.sum())
    if n:
        keep_gaussians(trainer.model, trainer.optimizer, ~mask)
        trainer.stats.keep(~mask)
    return n


class _Mirror(Technique):
    """The partner's side: its render of this step's pseudo view is pulled towards the main field's."""

    name = "coregularisation_mirror"

    def __init__(self, owner: "CoRegularisation"):
        self.owner = owner

    def loss_terms(self, ctx: StepContext) -> dict | None:
        camera = self.owner.current_camera
        if camera is None:
            return None
        out = ctx.trainer.render_for_training(ctx, camera, absgrad=False)
        with torch.no_grad():
            target = self.owner.trainer.render(camera).color
        return photometric_terms(out.color, target, ctx.trainer.config.lambda_dssim, weight=self.owner.weight,
                                 prefix="coreg_")


class CoRegularisation(Technique):
    """CoR-GS: a partner field, co-regularised at pseudo views and co-pruned (static scenes)."""

    name = "coregularisation"

    def __init__(self, weight: float = 1.0, start_fraction: float = 0.2, prune_every: int = 500,
                 prune_radius: float = 0.05):
        if not (np.isfinite(weight) and weight >= 0):
            raise GsgsError(f"co-regularisation weight must be >= 0, got {weight}")
        if not 0.0 <= start_fraction <= 1.0:
            raise GsgsError(f"co-regularisation start fraction must be in [0, 1], got {start_fraction}")
        self.weight = float(weight)
        self.start_fraction = float(start_fraction)
        self.prune_every = int(prune_every)
        self.prune_radius = float(prune_radius)  # a fraction of the trainer's size_extent
        self.partner = None
        self.trainer = None
        self.pool = []
        self.current_camera = None
        self.pruned = {"main": 0, "partner": 0}
        #: makes the partner's own instances of the run's other techniques (catalogue.make_techniques sets it)
        self.partner_techniques = None

    def install(self, trainer) -> None:
        from gsgs_engine.priors.poses import interpolated_pseudo_views
        from gsgs_engine.train.techniques.prior_loop import orbit_focus
        from gsgs_engine.train.trainer import Trainer

        if trainer.scene.has_time or type(trainer) is not Trainer:
            raise GsgsError("co-regularisation trains a second static field; it does not support 4D scenes")
        self.trainer = trainer
        cams = [v.camera for v in trainer.train_views]
        self.pool = [p.camera for p in interpolated_pseudo_views(cams, PSEUDO_POOL, 0.0, trainer.config.seed,
                                                                  focus=orbit_focus(cams))]
        if not self.pool:
            raise GsgsError("co-regularisation needs at least two training views to place pseudo views")
        ckpt_dir = None if trainer.checkpoint_dir is None else trainer.checkpoint_dir / self.name
        # its own copy of the settings as asked for: the main field's techniques adjust trainer.config's densify
        # settings in place (absgrad's threshold, the budget), and the partner's own techniques do the same to it
        config = replace(trainer.config_as_set_up(), seed=trainer.config.seed + 1, checkpoint_every=0)
        self.partner = Trainer(trainer.scene, config, checkpoint_dir=ckpt_dir, train_views=trainer.train_views)
        state = trainer.model.state_dict()
        state["params"] = {k: v.cpu() for k, v in state["params"].items()}  # the partner moves it to its device
        initial = type(trainer.model).from_state_dict(state)
        # a resumed main field (its step > 0) resumes the partner from its own checkpoint before the partner's
        # techniques are added, as the main field's were: add_technique hands each its saved state
        self.partner.setup(resume=trainer.step > 0 and ckpt_dir is not None, initial_model=initial)
        for technique in (self.partner_techniques() if self.partner_techniques else []):
            self.partner.add_technique(technique)
        self.partner.add_technique(_Mirror(self))

    def _start(self) -> int:
        return int(round(self.trainer.config.iters * self.start_fraction))

    def loss_terms(self, ctx: StepContext) -> dict | None:
        self.current_camera = None
        if ctx.step <= self._start() or self.weight == 0.0:
            return None
        camera = self.pool[int(ctx.trainer.np_rng.integers(len(self.pool)))]
        self.current_camera = camera
        out = ctx.trainer.render_for_training(ctx, camera, absgrad=False)
        with torch.no_grad():
            target = self.partner.render(camera).color
        return photometric_terms(out.color, target, ctx.trainer.config.lambda_dssim, weight=self.weight,
                                 prefix="coreg_")

    def after_step(self, trainer, step: int) -> None:
        self.partner.train_step()  # the same step for the partner, pulled towards the main field's update
        self.current_camera = None
        if (self.prune_every > 0 and step % self.prune_every == 0 and step <= trainer.schedule.densify_until):
            radius = self.prune_radius * trainer.size_extent
            main_means = trainer.model.means.detach().clone()
            self.pruned["main"] += prune_isolated(trainer, self.partner.model.means.detach(), radius)
            self.pruned["partner"] += prune_isolated(self.partner, main_means, radius)

    def state_dict(self) -> dict:
        path = self.partner.save_checkpoint() if self.partner is not None else None
        return {"partner_checkpoint_step": None if path is None else self.partner.step,
                "pruned": dict(self.pruned)}

    def load_state_dict(self, state: dict) -> None:
        step = state.get("partner_checkpoint_step")
        if step is None:
            return
        if self.partner.step != step:
            raise GsgsError(f"{self.partner.checkpoint_dir}: the partner field's checkpoint is at step "
                            f"{self.partner.step}, the run's at {step}; resume needs both (or start again)")
        self.pruned = dict(state.get("pruned", self.pruned))

    def report(self) -> dict:
        return {"weight": self.weight, "start_step": self._start() if self.trainer else None,
                "prune_every": self.prune_every, "prune_radius": self.prune_radius,
                "pruned": dict(self.pruned),
                "partner_gaussians": None if self.partner is None else self.partner.model.num_gaussians}
