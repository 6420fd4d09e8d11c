"""The depth regulariser (eq. 10) as a training technique.

Each step compares the rendered inverse depth of the training view (and of the step's pseudo
view, when the pseudo-view technique rendered one and a depth estimate of its target exists)
with the depth source's estimate through -MS-SSIM (gsgs_engine.priors.depth_reg). Depth
sources: a local depth-estimation model folder, or the SfM points of the training views
densified per view ("sparse").
"""

from __future__ import annotations

import numpy as np
import torch

from gsgs_engine.train.technique import StepContext, Technique

MIN_DEPTH_COVERAGE = 0.10  # share of training-view pixels a depth source must cover to regularise
MIN_MASK_PIXELS = 16  # a view whose estimate covers fewer pixels adds no term


def _matched(inverse_depth: torch.Tensor, mask: torch.Tensor, rendered: torch.Tensor):
    """An estimate and its mask resized to a render made at a reduced scale (coarse-to-fine steps,
    pseudo views rendered smaller); unchanged at the same size."""
    if tuple(rendered.shape) == tuple(inverse_depth.shape):
        return inverse_depth, mask
    from gsgs_engine.train.resample import resize_area

    h, w = rendered.shape
    return resize_area(inverse_depth.float(), h, w), resize_area(mask.float(), h, w) > 0.5


class DepthRegulariser(Technique):
    """L_reg = -MS-SSIM(rendered inverse depth, estimated inverse depth), weight `lambda_reg` (eq. 10, 11).

    `plan` is the prior's plan dict: the regulariser records there what it measured (coverage,
    number of SfM points) and switches itself off, saying why, when its source covers too little.
    """

    name = "depth_regulariser"

    def __init__(self, source: str, lambda_reg: float, plan: dict, sparse_points=None, log=print):
        self.source = source
        self.lambda_reg = float(lambda_reg)
        self.plan = plan
        self.log = log
        self._sparse_points = sparse_points
        self.sparse = None
        self.estimator = None
        self.enabled = True
        self.train_depth: list[tuple[torch.Tensor, torch.Tensor]] = []
        self.pseudo_depth: list[tuple[torch.Tensor, torch.Tensor]] = []  # aligned with the supervised pseudo views
        self.trainer = None

    def install(self, trainer) -> None:
        self.trainer = trainer
        if self.source == "sparse":
            from gsgs_engine.priors.sparse_depth import SparseDepthSource

            points = self._sparse_points
            if points is None:
                from gsgs_engine.sfm import triangulate_known_poses

                points, _ = triangulate_known_poses(trainer.train_views)
            self.sparse = SparseDepthSource(points)
            self.plan["sparse_points"] = int(len(self.sparse.points))
        else:
            from gsgs_engine.priors.depth_estimators import load_depth_estimator

            self.estimator = load_depth_estimator(self.source, device=str(trainer.device))
        self._sparse_points = None
        self.train_depth = [self.estimate(v.camera, trainer._targets[i]) for i, v in enumerate(trainer.train_views)]
        coverage = float(np.mean([float(m.float().mean()) for _, m in self.train_depth]))
        self.plan["depth_coverage"] = round(coverage, 4)
        if coverage < MIN_DEPTH_COVERAGE:
            # A depth map known on a few scattered pixels constrains nothing and adds noise.
            self.plan["depth_source_disabled"] = (f"the {self.source} depth covers {coverage:.1%} of the training "
                                                  f"views (< {MIN_DEPTH_COVERAGE:.0%})")
            self.plan["depth_source"] = None
            self.plan["lambda_reg"] = 0.0
            self.train_depth = []
            self.enabled = False
            self.log(f"depth regulariser off: {self.plan['depth_source_disabled']}")

    def estimate(self, camera, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(relative inverse depth, valid mask) of an image at a camera from the configured source,
        on the trainer's device (the depth sources answer on the CPU)."""
        if self.sparse is not None:
            inv, mask = self.sparse.estimate(camera, image)
        else:
            inv = self.estimator(image)
            mask = torch.isfinite(inv)
        device = self.trainer.device
        return inv.to(device), mask.to(device)

    def inverse_depth_of(self, image, depth=None, alpha=None) -> torch.Tensor:
        """The estimator's inverse depth of `image`, or (no estimator) the render's own."""
        from gsgs_engine.priors.depth_reg import inverse_depth

        if self.estimator is not None:
            return self.estimator(image)
        return inverse_depth(depth, alpha)

    def set_pseudo_depth(self, estimates: list[tuple[torch.Tensor, torch.Tensor]]) -> None:
        """Estimates of the supervised pseudo views' targets, in the pseudo-view technique's order."""
        self.pseudo_depth = list(estimates)

    # eq. 10 as a loss term
    def loss_terms(self, ctx: StepContext) -> dict | None:
        from gsgs_engine.priors.depth_reg import depth_regulariser, inverse_depth

        if not self.enabled:
            return None
        terms = []
        inv_t, mask_t = self.train_depth[ctx.view_index]
        inv_t, mask_t = _matched(inv_t, mask_t, ctx.render.depth)
        if mask_t.sum() > MIN_MASK_PIXELS:
            rendered = inverse_depth(ctx.render.depth, ctx.render.alpha)
            terms.append(depth_regulariser(rendered, inv_t, mask_t))
        pseudo = ctx.shared.get("pseudo")
        if pseudo is not None and self.pseudo_depth:
            j, _, out = pseudo
            inv_p, mask_p = _matched(*self.pseudo_depth[j], out.depth)
            if mask_p.sum() > MIN_MASK_PIXELS:
                rendered = inverse_depth(out.depth, out.alpha)
                terms.append(depth_regulariser(rendered, inv_p, mask_p))
        if not terms:
            return None
        return {"depth_reg": (self.lambda_reg, torch.stack(terms).mean())}

    def report(self) -> dict:
        return {"source": self.source, "enabled": self.enabled, "lambda_reg": self.lambda_reg}
