"""Progressive Gaussian dropout (DropGaussian) as a training technique.

Every training render (the training view and any view a technique supervises through
`Trainer.render_for_training`) sees each Gaussian's opacity multiplied by a random keep mask
scaled by 1 / (1 - p), so the expected opacity is unchanged; p ramps linearly from 0 at the
first step to `max_rate` at the last. Gaussians that a few others hide get gradients, and no
single Gaussian can carry a training pixel alone. Evaluation renders (`Trainer.render`) use
every Gaussian at its own opacity.

`guide=density` (after D2GS's depth-and-density guided dropout) keeps the mean rate of the schedule
but shares it out unevenly: a Gaussian's drop probability is p x s_i / mean(s), where the score s_i
mixes how crowded its neighbourhood is (its voxel's Gaussian count, as a percentile; 0.85) and how
near the rendering camera it is (0.15). Crowded clusters near the cameras are where a few views
overfit; lone Gaussians far away are the ones a sparse capture can least afford to lose. The
neighbourhood counts are refreshed every `DENSITY_REFRESH` steps and whenever the Gaussian count
changes (they are checkpointed, so a resumed run uses the same ones).

`guide=anchor` (after DropAnSH-GS's anchor dropout) drops whole neighbourhoods, the same voxels,
at the schedule's rate: a hole the size of a neighbourhood must be filled by Gaussians elsewhere,
where dropping single Gaussians lets their neighbours cover for them.

`sh_rate=P` (DropAnSH-GS's SH dropout, their P = 0.2) also truncates each Gaussian's view-dependent colour at
random in every training render: band l >= 1 is dropped with probability P, and with it every band above, so the
low bands must carry the colour on their own and the high bands only add to it (`dropout_sh_bands`). It is not
ramped; evaluation renders use every band.

The mask is drawn from the trainer's seeded CPU generator (`trainer.torch_gen`), which the
trainer checkpoints: a run is deterministic and resumes bit-identically.
"""

from __future__ import annotations

import torch

from gsgs_engine import GsgsError
from gsgs_engine.train.technique import StepContext, Technique, joined_sh

DEFAULT_MAX_RATE = 0.2  # DropGaussian's final drop rate
GUIDES = ("uniform", "density", "anchor")
DENSITY_WEIGHT = 0.85  # D2GS's weight of density against nearness to the camera
DENSITY_REFRESH = 100  # steps between recounts of the neighbourhoods (densification's own interval)
VOXEL_OCCUPANCY = 8.0  # voxel size chosen so that an even spread would put this many Gaussians in each
MAX_GUIDED_RATE = 0.9  # no Gaussian is dropped with a higher probability than this


def drop_rate(step: int, iters: int, max_rate: float = DEFAULT_MAX_RATE) -> float:
    """p at 1-based `step` of `iters`: linear from 0 to `max_rate` over training."""
    return float(max_rate) * min(max(step / max(iters, 1), 0.0), 1.0)


def dropout_opacities(opacities: torch.Tensor, rate: float, generator: torch.Generator) -> torch.Tensor:
    """opacities * keep / (1 - rate), keep ~ Bernoulli(1 - rate) per Gaussian (unbiased in expectation)."""
    if rate <= 0.0:
        return opacities
    keep = (torch.rand(opacities.shape[0], generator=generator) >= rate).to(opacities.device, opacities.dtype)
    return opacities * keep.reshape(-1, *([1] * (opacities.ndim - 1))) / (1.0 - rate)


def dropout_sh_bands(sh: torch.Tensor, rate: float, generator: torch.Generator) -> torch.Tensor:
    """sh [N, (D+1)^2, 3] with each Gaussian's bands above a random degree zeroed: band l = 1..D is dropped with
    probability `rate`, and a dropped band drops the bands above it (P(degree d kept) = (1 - rate)^d). Degree 0
    (the base colour) is never dropped; no rescaling (colour is not a sum of independent parts)."""
    n, k = sh.shape[0], sh.shape[1]
    degree = int(round(k ** 0.5)) - 1
    if rate <= 0.0 or degree < 1 or n == 0:
        return sh
    dropped = torch.rand(n, degree, generator=generator) < rate
    # the highest degree kept: the first dropped band's index (bands 1..D at columns 0..D-1), else D
    kept = torch.where(dropped.any(dim=1), dropped.to(torch.int8).argmax(dim=1), torch.full((n,), degree))
    band = torch.arange(k).float().sqrt().floor().to(torch.int64)  # band of each coefficient
    keep = (band[None, :] <= kept[:, None]).to(sh.device, sh.dtype)
    return sh * keep[..., None]


def percentiles(values: torch.Tensor) -> torch.Tensor:
    """Each value's mid-rank percentile in [0, 1] (ties share one): scale-free and deterministic."""
    ordered, _ = torch.sort(values)
    below = torch.searchsorted(ordered, values, right=False)
    up_to = torch.searchsorted(ordered, values, right=True)
    return (below + up_to).to(torch.float32) / (2.0 * max(values.numel(), 1))


def voxel_cells(means: torch.Tensor) -> torch.Tensor:
    """Each Gaussian's voxel as an index 0..M-1; voxels sized from the robust bounding box.

    The box spans the 2nd-98th percentiles of the centres (so a few far Gaussians do not make the
    voxels huge) and the voxel edge is chosen so an even spread would put VOXEL_OCCUPANCY
    Gaussians in each; centres outside the box fall in the voxels beyond it. A non-finite centre
    gets a voxel of its own.
    """
    n = means.shape[0]
    x = means.detach().to("cpu", torch.float64)
    finite = torch.isfinite(x).all(dim=1)
    if n < 2 or not bool(finite.any()):
        return torch.arange(n)
    sample = x[finite][:: max(1, int(finite.sum()) // 4096)]
    lo = torch.quantile(sample, 0.02, dim=0)
    hi = torch.quantile(sample, 0.98, dim=0)
    extent = torch.clamp(hi - lo, min=1e-9 * float(torch.clamp((hi - lo).max(), min=1e-30)))
    edge = max(float((extent.prod() * VOXEL_OCCUPANCY / n) ** (1.0 / 3.0)), 1e-30)
    cells = torch.floor((torch.where(finite[:, None], x, lo) - lo) / edge).clamp(-2**20, 2**20).to(torch.int64)
    cells -= cells.min(dim=0).values
    span = cells.max(dim=0).values + 1
    key = (cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2]
    key[~finite] = -1 - torch.arange(int((~finite).sum()))  # alone, below every real voxel's key
    return torch.unique(key, return_inverse=True)[1]


def neighbourhood_density(means: torch.Tensor, cells: torch.Tensor | None = None) -> torch.Tensor:
    """Percentile of each Gaussian's voxel count (`voxel_cells`): 1 in the most crowded voxels."""
    n = means.shape[0]
    if n < 2:
        return torch.full((n,), 0.5)
    cells = voxel_cells(means) if cells is None else cells
    counts = torch.bincount(cells)
    return percentiles(counts[cells].to(torch.float32))


def anchor_dropout_opacities(opacities: torch.Tensor, rate: float, cells: torch.Tensor,
                             generator: torch.Generator) -> torch.Tensor:
    """Whole voxels (a Gaussian and its neighbours: DropAnSH-GS's anchors) dropped with probability
    `rate`, the kept ones scaled by 1 / (1 - rate): unbiased, as the uniform mask."""
    if rate <= 0.0:
        return opacities
    n_cells = int(cells.max()) + 1 if cells.numel() else 0
    keep_cell = (torch.rand(n_cells, generator=generator) >= rate).to(torch.float32)
    factor = (keep_cell[cells] / (1.0 - rate)).to(opacities.device, opacities.dtype)
    return opacities * factor.reshape(-1, *([1] * (opacities.ndim - 1)))


def nearness(means: torch.Tensor, camera) -> torch.Tensor:
    """1 for the nearest Gaussians in front of `camera`, 0 for the farthest (robust 2-98% range)."""
    R = torch.as_tensor(camera.R, dtype=torch.float32)
    t = torch.as_tensor(camera.t, dtype=torch.float32)
    z = means.detach().to("cpu", torch.float32) @ R[2] + t[2]
    z = torch.nan_to_num(z, nan=float("inf"), posinf=float("inf"), neginf=float("inf"))
    ok = torch.isfinite(z) & (z > 0)
    if not bool(ok.any()):
        return torch.zeros_like(z)
    sample = z[ok][:: max(1, int(ok.sum()) // 4096)]
    near, far = torch.quantile(sample, 0.02), torch.quantile(sample, 0.98)
    return torch.where(ok, ((far - z) / torch.clamp(far - near, min=1e-12)).clamp(0.0, 1.0), torch.zeros_like(z))


def guided_dropout_opacities(opacities: torch.Tensor, rate: float, score: torch.Tensor,
                             generator: torch.Generator) -> torch.Tensor:
    """opacities * keep_i / (1 - p_i) with p_i = rate * score_i / mean(score) (at most MAX_GUIDED_RATE).

    Unbiased per Gaussian; the mean drop probability is `rate` unless the cap clips it.
    """
    if rate <= 0.0:
        return opacities
    mean = float(score.mean()) if score.numel() else 0.0
    p = (rate * score / mean) if mean > 0 else torch.full_like(score, rate)
    p = p.clamp(0.0, MAX_GUIDED_RATE)
    keep = (torch.rand(opacities.shape[0], generator=generator) >= p).to(torch.float32)
    factor = (keep / (1.0 - p)).to(opacities.device, opacities.dtype)
    return opacities * factor.reshape(-1, *([1] * (opacities.ndim - 1)))


class GaussianDropout(Technique):
    name = "dropout"

    def __init__(self, max_rate: float = DEFAULT_MAX_RATE, guide: str = "uniform", sh_rate: float = 0.0):
        if not 0.0 <= max_rate < 1.0:
            raise GsgsError(f"dropout: the final drop rate must be in [0, 1) (got {max_rate})")
        if not 0.0 <= sh_rate < 1.0:
            raise GsgsError(f"dropout: sh_rate (the SH band drop probability) must be in [0, 1) (got {sh_rate}; "
                            "e.g. dropout:sh_rate=0.2)")
        if guide not in GUIDES:
            raise GsgsError(f"dropout: guide must be one of {', '.join(GUIDES)} (got {guide!r}; "
                            "e.g. dropout:guide=density)")
        self.max_rate = float(max_rate)
        self.guide = guide
        self.sh_rate = float(sh_rate)
        self.trainer = None
        self.renders_dropped = 0
        self.last_rate = 0.0
        self._cells = None  # each Gaussian's voxel (guides density and anchor), refreshed as DENSITY_REFRESH says
        self._density = None  # percentile of each Gaussian's voxel count (guide=density)
        self._density_step = 0
        self._near = None  # (step, camera, the means it was made from, nearness) of the last render

    def _refresh(self, means: torch.Tensor, step: int) -> None:
        stale = self._cells is None or self._cells.shape[0] != means.shape[0]
        if stale or step - self._density_step >= DENSITY_REFRESH:
            self._cells = voxel_cells(means)
            self._density = neighbourhood_density(means, self._cells)
            self._density_step = step

    def install(self, trainer) -> None:
        self.trainer = trainer

    def _nearness(self, means: torch.Tensor, ctx: StepContext) -> torch.Tensor:
        """`nearness` to the step's camera, made once a step: every render of a step (the training view, the
        binocular and pseudo views) passes the same means and names the same camera."""
        cached = self._near
        if cached is None or cached[0] != ctx.step or cached[1] is not ctx.camera or cached[2] is not means:
            cached = self._near = (ctx.step, ctx.camera, means, nearness(means, ctx.camera))
        return cached[3]

    def render_inputs(self, ctx: StepContext, inputs: dict) -> dict:
        if self.sh_rate > 0.0 and inputs.get("sh_degree", 0) > 0:
            inputs = joined_sh(inputs)
            inputs = {**inputs, "sh": dropout_sh_bands(inputs["sh"], self.sh_rate, ctx.trainer.torch_gen)}
        return self._opacity_inputs(ctx, inputs)

    def _opacity_inputs(self, ctx: StepContext, inputs: dict) -> dict:
        tr = ctx.trainer
        rate = drop_rate(ctx.step, tr.config.iters, self.max_rate)
        self.last_rate = rate
        if rate <= 0.0:
            return inputs
        self.renders_dropped += 1
        if self.guide == "uniform":
            return {**inputs, "opacities": dropout_opacities(inputs["opacities"], rate, tr.torch_gen)}
        self._refresh(inputs["means"], ctx.step)
        if self.guide == "anchor":
            return {**inputs, "opacities": anchor_dropout_opacities(inputs["opacities"], rate, self._cells,
                                                                    tr.torch_gen)}
        # the trainer always names the step's camera; a caller without one gets the density term alone
        near = self._nearness(inputs["means"], ctx) if ctx.camera is not None else self._density
        score = DENSITY_WEIGHT * self._density + (1.0 - DENSITY_WEIGHT) * near
        return {**inputs, "opacities": guided_dropout_opacities(inputs["opacities"], rate, score, tr.torch_gen)}

    def state_dict(self) -> dict:
        state = {"renders_dropped": self.renders_dropped, "last_rate": self.last_rate}
        if self._cells is not None:
            state.update(cells=self._cells.clone(), density=self._density.clone(), density_step=self._density_step)
        return state

    def load_state_dict(self, state: dict) -> None:
        self.renders_dropped = int(state.get("renders_dropped", 0))
        self.last_rate = float(state.get("last_rate", 0.0))
        self._cells = state.get("cells")
        self._density = state.get("density")
        self._density_step = int(state.get("density_step", 0))

    def report(self) -> dict:
        return {"max_rate": self.max_rate, "guide": self.guide, "sh_rate": self.sh_rate,
                "schedule": "linear 0 -> max_rate over the run, training renders only",
                "renders_dropped": self.renders_dropped, "final_rate": round(self.last_rate, 4)}
