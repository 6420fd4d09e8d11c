"""Cross-view photometric consistency: the other training photos, warped by the rendered depth.

A photo says nothing about depth by itself: with 3 views, each view's loss is met by geometry that only that view
checks, and the binocular term (a render of the model's own shifted view) cannot tell a consistent surface at the
wrong depth from the right one. The other training photos can. From `start_fraction` of the run on, each step
takes the surface depth rendered at the training view (alpha-weighted depth over alpha), reprojects every pixel
into each of the `neighbours` nearest other training cameras (priors.warp.backward_warp), samples that camera's
photo there and compares it with the training photo:

    e_j(p) = mean over channels |G * I_j(pi_j(z_i(p), p)) - G * I_i(p)|,   L = mean_p m(p) min_j e_j(p)

(the minimum over neighbours: a pixel occluded in one neighbour is usually seen in another). Both photos are
blurred by a Gaussian of `blur` pixels (G *): bilinear sampling's gradient sees one pixel around each sample, and
between the cameras of a sparse rig a depth error of a few pixels' parallax is common, so the blur widens the
reach of the photometric gradient to the error it must correct. The mask m keeps the pixels where the render is
opaque (alpha > 0.5), the warp lands inside a neighbour's photo, and (`auto_mask`, monodepth2's automatic mask)
the warped error is below the error of the neighbour's photo taken unwarped: flat regions, where any depth
matches, give no gradient. The gradient reaches the depth (through the sampling positions) and the alpha of
the training render; the photos are data.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from gsgs_engine import GsgsError
from gsgs_engine.train.technique import StepContext, Technique

DEFAULT_WEIGHT = 0.5
DEFAULT_START_FRACTION = 0.6
DEFAULT_BLUR = 2.0  # pixels (Gaussian sigma) at the training view's full resolution
DEFAULT_NEIGHBOURS = 2
MIN_OPAQUE = 0.5


def nearest_cameras(centres, k: int) -> list[list[int]]:
    """For each camera centre, the indices of its `k` nearest other centres (fewer when there are fewer)."""
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    d = np.linalg.norm(c[:, None] - c[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    order = np.argsort(d, axis=1, kind="stable")
    return [[int(j) for j in order[i, :min(k, len(c) - 1)]] for i in range(len(c))]


def gaussian_blur(image: torch.Tensor, sigma: float) -> torch.Tensor:
    """(H, W, C) image blurred by a separable Gaussian of `sigma` pixels (edges replicated); sigma 0: unchanged."""
    if sigma <= 0:
        return image
    r = max(1, int(np.ceil(3 * sigma)))
    x = torch.arange(-r, r + 1, dtype=image.dtype, device=image.device)
    k = torch.exp(-0.5 * (x / sigma) ** 2)
    k = k / k.sum()
    c = image.shape[-1]
    t = image.permute(2, 0, 1)[None]
    t = F.conv2d(F.pad(t, (r, r, 0, 0), mode="replicate"), k.view(1, 1, 1, -1).expand(c, 1, 1, -1), groups=c)
    t = F.conv2d(F.pad(t, (0, 0, r, r), mode="replicate"), k.view(1, 1, -1, 1).expand(c, 1, -1, 1), groups=c)
    return t[0].permute(1, 2, 0).contiguous()


class CrossViewConsistency(Technique):
    name = "cross_view"

    def __init__(self, weight: float = DEFAULT_WEIGHT, start_fraction: float = DEFAULT_START_FRACTION,
                 blur: float = DEFAULT_BLUR, neighbours: int = DEFAULT_NEIGHBOURS, auto_mask: int = 1):
        if weight < 0:
            raise GsgsError(f"cross_view: the weight must be >= 0 (got {weight})")
        if not 0.0 <= start_fraction < 1.0:
            raise GsgsError(f"cross_view: start_fraction must be in [0, 1) (got {start_fraction})")
        if blur < 0:
            raise GsgsError(f"cross_view: blur is a Gaussian's sigma in pixels, >= 0 (got {blur})")
        if not (isinstance(neighbours, int) and neighbours >= 1):
            raise GsgsError(f"cross_view: neighbours must be a whole number >= 1 (got {neighbours!r})")
        if auto_mask not in (0, 1):
            raise GsgsError(f"cross_view: auto_mask is 0 or 1 (got {auto_mask!r})")
        self.weight, self.start_fraction, self.blur = float(weight), float(start_fraction), float(blur)
        self.neighbours, self.auto_mask = neighbours, auto_mask
        self.start = 1
        self.pairs: list[list[int]] = []
        self._blurred: dict = {}
        self.steps = 0
        self.last_used = 0.0

    def install(self, trainer) -> None:
        self.start = max(1, int(round(self.start_fraction * trainer.config.iters)) + 1)
        self.pairs = nearest_cameras([v.camera.center for v in trainer.train_views], self.neighbours)
        self._blurred = {}

    def _photo(self, trainer, j: int, camera) -> torch.Tensor:
        """Training photo j blurred, at the size of `camera` (view j's camera at some scale)."""
        key = (j, camera.width, camera.height)
        if key not in self._blurred:
            img = trainer._targets[j]
            if (img.shape[1], img.shape[0]) != (camera.width, camera.height):
                from gsgs_engine.train.resample import resize_area
                img = resize_area(img, camera.height, camera.width)
            self._blurred[key] = gaussian_blur(img, self.blur * camera.width / trainer.train_views[j].camera.width)
        return self._blurred[key]

    def loss_terms(self, ctx: StepContext) -> dict | None:
        if ctx.step < self.start or self.weight == 0:
            return None
        from gsgs_engine.priors.warp import backward_warp
        from gsgs_engine.train.techniques.binocular import surface_depth

        tr = ctx.trainer
        i = ctx.view_index
        if not self.pairs or not self.pairs[i]:
            return None
        camera = ctx.camera if ctx.camera is not None else tr.train_views[i].camera
        scale = camera.width / tr.train_views[i].camera.width
        plain = ctx.target is tr._targets[i] or ctx.target is tr._reduced_targets.get((i, camera.width, camera.height))
        target = self._photo(tr, i, camera) if plain else gaussian_blur(ctx.target, self.blur * scale)
        z = surface_depth(ctx.render.depth, ctx.render.alpha)
        best = None
        ident = None
        any_valid = torch.zeros(z.shape, dtype=torch.bool, device=z.device)
        for j in self.pairs[i]:
            cam_j = tr.train_views[j].camera
            if scale != 1.0:
                cam_j = cam_j.scaled(scale)
            photo_j = self._photo(tr, j, cam_j)
            sampled, valid = backward_warp(camera, z, cam_j, photo_j)
            err = (sampled - target).abs().mean(-1)
            err = torch.where(valid, err, torch.full_like(err, float("inf")))
            best = err if best is None else torch.minimum(best, err)
            any_valid |= valid
            if self.auto_mask and photo_j.shape == target.shape:
                e0 = (photo_j - target).abs().mean(-1).detach()
                ident = e0 if ident is None else torch.minimum(ident, e0)
        mask = any_valid & (ctx.render.alpha.detach() > MIN_OPAQUE)
        if ident is not None:
            mask &= best.detach() < ident
        best = torch.where(mask, best, torch.zeros_like(best))
        self.steps += 1
        self.last_used = float(mask.float().mean())
        return {"cross_view_l1": (self.weight, best.mean())}

    def state_dict(self) -> dict:
        return {"steps": self.steps}

    def load_state_dict(self, state: dict) -> None:
        self.steps = int(state.get("steps", 0))

    def report(self) -> dict:
        return {"weight": self.weight, "start_step": self.start, "blur": self.blur, "neighbours": self.neighbours,
                "auto_mask": self.auto_mask, "pairs": self.pairs, "steps": self.steps,
                "last_used_fraction": round(self.last_used, 4)}
