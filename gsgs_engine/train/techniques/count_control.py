"""Gaussian-count control for sparse views: a budget tied to the training pixels.

With 3-8 photos 3DGS's fixed densification settings give whatever count the gradients happen
to produce: 150k Gaussians on LLFF flower's 3 views (each one fitting a few pixels of one photo,
which is over-fitting), 7.4k on an orbit whose SfM points miss thin structures (too few to
grow them). This technique ties the count to the evidence, the number of training pixels P:

- a ceiling: at most `per_pixel` x P Gaussians (the trainer's densification honours
  `DensifyConfig.max_gaussians`, keeping the strongest gradients within the budget);
- a floor by threshold: at a densification step with fewer than `floor_fraction` of the budget,
  the gradient threshold is lowered in proportion (down to `min_threshold_scale` x the base), so
  a model far below its budget keeps growing where the photos still disagree with it.

Both act only through the trainer's densification settings, before each densification step.
"""

from __future__ import annotations

from gsgs_engine import GsgsError
from gsgs_engine.train.technique import Technique

DEFAULT_PER_PIXEL = 0.1
DEFAULT_FLOOR_FRACTION = 0.5
DEFAULT_MIN_THRESHOLD_SCALE = 0.25


def gaussian_budget(train_views, per_pixel: float) -> int:
    """per_pixel x the number of pixels of the training views (at least 1000)."""
    pixels = sum(int(v.camera.width) * int(v.camera.height) for v in train_views)
    return max(1000, int(round(per_pixel * pixels)))


def threshold_scale(num_gaussians: int, budget: int, floor_fraction: float, min_scale: float) -> float:
    """1 at or above floor_fraction x budget; proportionally lower below it, never under min_scale."""
    floor = floor_fraction * budget
    if floor <= 0 or num_gaussians >= floor:
        return 1.0
    return max(min_scale, num_gaussians / floor)


class GaussianBudget(Technique):
    name = "count_control"

    def __init__(self, per_pixel: float = DEFAULT_PER_PIXEL, floor_fraction: float = DEFAULT_FLOOR_FRACTION,
                 min_threshold_scale: float = DEFAULT_MIN_THRESHOLD_SCALE):
        if per_pixel <= 0:
            raise GsgsError(f"count_control: per_pixel must be positive (got {per_pixel})")
        if not 0 <= floor_fraction <= 1 or not 0 < min_threshold_scale <= 1:
            raise GsgsError(f"count_control: floor_fraction must be in [0, 1] and min_threshold_scale in (0, 1] "
                            f"(got {floor_fraction}, {min_threshold_scale})")
        self.per_pixel, self.floor_fraction = float(per_pixel), float(floor_fraction)
        self.min_threshold_scale = float(min_threshold_scale)
        self.budget = 0
        self.base_threshold: float | None = None
        self.lowered_steps = 0
        self.last_scale = 1.0

    def install(self, trainer) -> None:
        self.budget = gaussian_budget(trainer.train_views, self.per_pixel)
        dc = trainer.config.densify_config
        dc.max_gaussians = min(int(dc.max_gaussians), self.budget)
        if self.base_threshold is None:
            self.base_threshold = float(dc.grad_threshold)

    def before_step(self, trainer, step: int) -> None:
        sched = trainer.schedule
        if not (trainer.config.densify and sched.is_densify_step(step)):
            return
        scale = threshold_scale(trainer.model.num_gaussians, self.budget, self.floor_fraction,
                                self.min_threshold_scale)
        trainer.config.densify_config.grad_threshold = self.base_threshold * scale
        self.last_scale = scale
        if scale < 1.0:
            self.lowered_steps += 1

    def state_dict(self) -> dict:
        return {"base_threshold": self.base_threshold, "lowered_steps": self.lowered_steps,
                "last_scale": self.last_scale}

    def load_state_dict(self, state: dict) -> None:
        self.base_threshold = float(state["base_threshold"])
        self.lowered_steps = int(state.get("lowered_steps", 0))
        self.last_scale = float(state.get("last_scale", 1.0))

    def report(self) -> dict:
        return {"per_pixel": self.per_pixel, "budget": self.budget, "floor_fraction": self.floor_fraction,
                "min_threshold_scale": self.min_threshold_scale, "base_grad_threshold": self.base_threshold,
                "densify_steps_with_lowered_threshold": self.lowered_steps,
                "last_threshold_scale": round(self.last_scale, 4)}
