"""Proximity-guided Gaussian unpooling (FSGS, Zhu et al. 2024, section 3.2) as a training technique.

With 3-8 photos the initial points are dense where the views matched and sparse elsewhere, and 3DGS's
densification only grows where a screen-space gradient is large, so a sparse region with a roughly right colour
stays sparse and renders with holes at the views between the photos. FSGS grows Gaussians into such regions from
the geometry instead of the gradient:

- proximity score (FSGS's P_i): the mean distance of Gaussian i to its K nearest Gaussians (`proximity_scores`);
- unpooling: a Gaussian whose score passes a threshold is a "source"; a new Gaussian is placed at the midpoint of
  each edge from it to one of its K neighbours (the "destination"), with the destination's scale and opacity
  (`unpooled_rows`).

Where this implementation decides for itself (FSGS's paper leaves these open or scene-tuned):
- The threshold is relative, not FSGS's absolute distance (which is tuned to a dataset's normalisation): the score
  is divided by the Gaussian's distance to the nearest training camera centre (so it measures the gap as an angle,
  as the photos see it, and a far background is not "sparse" because it is far), and a source scores above
  `ratio` x the median of those angular scores. Nothing is tuned to a scene.
- The new Gaussian's rotation is the destination's and its colour (all SH bands) the mean of the two ends' (FSGS
  sets them to zero: a grey blob until it is fitted; the mean is what a midpoint between two surfaces of known
  colour most likely shows). Each unordered pair is unpooled once.
- Growth stays inside the trainer's Gaussian budget (`DensifyConfig.max_gaussians`; count_control lowers it), most
  isolated sources first, and at most `max_fraction` x the model's count per event.

It runs after the trainer's own densification of a step, every `every` steps between the start of densification
and `until` x the run's steps (FSGS: before the late steps, so every new Gaussian is fitted long enough). Static
(3D) models only. No randomness: a resumed run unpools exactly as an uninterrupted one.
"""

from __future__ import annotations

import numpy as np
import torch

from gsgs_engine import GsgsError
from gsgs_engine.gaussians import nearest_neighbours
from gsgs_engine.train.densify import append_gaussians
from gsgs_engine.train.technique import Technique

DEFAULT_EVERY = 100
DEFAULT_UNTIL = 0.5
DEFAULT_K = 3  # FSGS's K
DEFAULT_RATIO = 3.0
DEFAULT_MAX_FRACTION = 0.05
DEFAULT_MIN_OPACITY = 0.0


def proximity_scores(means: torch.Tensor, k: int, centres: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(FSGS's proximity score divided by the distance to the nearest camera centre [N], neighbour indices [N, k]).

    The score is the mean Euclidean distance to the k nearest Gaussians; the division makes it the angle the gap
    subtends at the nearest camera. Non-finite means score 0 and are nobody's neighbour worth unpooling to."""
    n = means.shape[0]
    finite = torch.isfinite(means).all(dim=1)
    pts = torch.where(finite[:, None], means, torch.zeros_like(means))
    d2, idx = nearest_neighbours(pts, k)
    dist = d2.clamp_min(0).sqrt().mean(dim=1) if d2.shape[1] else torch.zeros(n, dtype=means.dtype)
    to_camera = torch.cdist(pts, centres.to(pts.dtype)).min(dim=1).values
    score = dist / to_camera.clamp_min(1e-12)
    score = torch.where(finite & torch.isfinite(score), score, torch.zeros_like(score))
    return score, idx


def unpool_pairs(score: torch.Tensor, idx: torch.Tensor, ratio: float, limit: int,
                 finite: torch.Tensor | None = None) -> torch.Tensor:
    """The (source, destination) pairs to unpool [M, 2], M <= limit: sources score above `ratio` x the median
    score of the eligible ones (`finite`: True where a Gaussian may be an end), most isolated first; each
    unordered pair once; no pair with itself or an ineligible end."""
    n = score.shape[0]
    if n < 2 or idx.shape[1] == 0 or limit <= 0:
        return torch.zeros(0, 2, dtype=torch.int64)
    finite = torch.ones(n, dtype=torch.bool) if finite is None else finite
    threshold = ratio * float(score[finite].median()) if bool(finite.any()) else float("inf")
    sources = torch.nonzero((score > threshold) & finite).flatten()
    if sources.numel() == 0:
        return torch.zeros(0, 2, dtype=torch.int64)
    sources = sources[torch.argsort(score[sources], descending=True, stable=True)]
    k = idx.shape[1]
    pairs = torch.stack([sources.repeat_interleave(k), idx[sources].reshape(-1)], dim=1)
    pairs = pairs[(pairs[:, 0] != pairs[:, 1]) & finite[pairs[:, 1]]]
    lo, hi = pairs.min(dim=1).values, pairs.max(dim=1).values
    _, first = np.unique((lo * n + hi).numpy(), return_index=True)  # first occurrence keeps the isolation order
    pairs = pairs[torch.from_numpy(np.sort(first))]
    return pairs[:limit]


def unpooled_rows(params: dict[str, torch.Tensor], pairs: torch.Tensor) -> dict[str, torch.Tensor]:
    """New parameter rows, one per (source, destination) pair: at the midpoint; the destination's scale, opacity
    and rotation; the mean of both ends' SH coefficients."""
    src, dst = pairs[:, 0], pairs[:, 1]
    rows = {name: value[dst].clone() for name, value in params.items()}
    rows["means"] = 0.5 * (params["means"][src] + params["means"][dst])
    rows["sh_dc"] = 0.5 * (params["sh_dc"][src] + params["sh_dc"][dst])
    rows["sh_rest"] = 0.5 * (params["sh_rest"][src] + params["sh_rest"][dst])
    return rows


class ProximityUnpooling(Technique):
    name = "unpool"

    def __init__(self, every: int = DEFAULT_EVERY, until: float = DEFAULT_UNTIL, k: int = DEFAULT_K,
                 ratio: float = DEFAULT_RATIO, max_fraction: float = DEFAULT_MAX_FRACTION,
                 min_opacity: float = DEFAULT_MIN_OPACITY):
        if int(every) < 1 or not 0.0 < float(until) <= 1.0 or int(k) < 1:
            raise GsgsError(f"unpool: every >= 1 step, until in (0, 1] of the run and k >= 1 are needed "
                            f"(got every={every}, until={until}, k={k})")
        if not float(ratio) > 0 or not 0.0 < float(max_fraction) <= 1.0:
            raise GsgsError(f"unpool: ratio > 0 (x the median proximity) and max_fraction in (0, 1] are needed "
                            f"(got ratio={ratio}, max_fraction={max_fraction})")
        self.every, self.until, self.k = int(every), float(until), int(k)
        if not 0.0 <= float(min_opacity) < 1.0:
            raise GsgsError(f"unpool: min_opacity in [0, 1) is needed (got {min_opacity})")
        self.ratio, self.max_fraction = float(ratio), float(max_fraction)
        self.min_opacity = float(min_opacity)
        self.added = 0
        self.events = 0
        self.wanted = 0  # pairs that passed the threshold, before the budget and the per-event cap
        self.centres: torch.Tensor | None = None

    def install(self, trainer) -> None:
        from gsgs_engine.train.trainer import Trainer

        if trainer.scene.has_time or type(trainer) is not Trainer:
            raise GsgsError("unpool grows static (3D) Gaussians; it does not support 4D scenes")
        self.centres = torch.as_tensor(np.stack([v.camera.center for v in trainer.train_views]), dtype=torch.float32)

    def _last_step(self, trainer) -> int:
        return int(round(trainer.config.iters * self.until))

    def after_step(self, trainer, step: int) -> None:
        sched = trainer.schedule
        if not trainer.config.densify or step % self.every or not sched.densify_from < step <= self._last_step(trainer):
            return
        if step >= trainer.config.iters:
            return
        model = trainer.model
        n = model.num_gaussians
        room = min(int(trainer.config.densify_config.max_gaussians) - n, int(self.max_fraction * n))
        with torch.no_grad():
            means = model.means.detach().to("cpu", torch.float32)
            score, idx = proximity_scores(means, self.k, self.centres)
            eligible = torch.isfinite(means).all(dim=1)
            if self.min_opacity > 0:  # both ends opaque: a fading floater is no source and no destination
                eligible &= model.opacities.detach().cpu() >= self.min_opacity
            pairs = unpool_pairs(score, idx, self.ratio, n * self.k, eligible)
            self.wanted += int(pairs.shape[0])
            pairs = pairs[:max(room, 0)]
            self.events += 1
            if pairs.shape[0] == 0:
                return
            params = {name: value.detach() for name, value in model.params.items()}
            rows = unpooled_rows(params, pairs.to(model.means.device))
        append_gaussians(model, trainer.optimizer, rows)
        trainer.stats.grow(int(pairs.shape[0]))
        self.added += int(pairs.shape[0])

    def state_dict(self) -> dict:
        return {"added": self.added, "events": self.events, "wanted": self.wanted}

    def load_state_dict(self, state: dict) -> None:
        self.added = int(state.get("added", 0))
        self.events = int(state.get("events", 0))
        self.wanted = int(state.get("wanted", 0))

    def report(self) -> dict:
        return {"every": self.every, "until": self.until, "k": self.k, "ratio": self.ratio,
                "max_fraction": self.max_fraction, "min_opacity": self.min_opacity, "events": self.events,
                "added": self.added, "wanted": self.wanted}
