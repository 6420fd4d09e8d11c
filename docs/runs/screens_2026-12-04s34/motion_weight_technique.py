"""More weight on the pixels of a video that move (issue 31, item 3: 4D on real video).

On a multi-view video most of every view is the still room, so the photometric loss spends most of its
gradient there, and the people, a small share of the pixels, are fitted last. From the training views alone
(no test view): per physical camera with at least three frames, the pixels whose colour differs from that
camera's per-pixel median over its frames by more than 0.1 in some channel (the changing pixels the dynamic
bench scores, bench/dynamic_region.changing_pixels) get an extra L1 term,

    "motion_l1" = weight x mean over the view's pixels of |render - photo| on those pixels,

so their L1 weight is 1 + `weight` (the D-SSIM term is unchanged). A view of a camera with fewer than three
frames (a static scene, one frame of a video) gets nothing: the technique needs the video to tell motion from
the room.
"""

from __future__ import annotations

import numpy as np
import torch

from gsgs_engine import GsgsError
from gsgs_engine.train.technique import StepContext, Technique

DEFAULT_WEIGHT = 1.0


class MotionWeight(Technique):
    name = "motion_weight"

    def __init__(self, weight: float = DEFAULT_WEIGHT):
        if not (np.isfinite(weight) and weight >= 0):
            raise GsgsError(f"motion_weight: the weight must be >= 0 (got {weight})")
        self.weight = float(weight)
        self.masks: dict[int, torch.Tensor] = {}
        self.moving_share = 0.0

    def install(self, trainer) -> None:
        from gsgs_engine.bench.dynamic_region import MIN_FRAMES_FOR_CHANGE, changing_pixels
        from gsgs_engine.train.techniques.exposure import camera_key

        by_camera: dict = {}
        for i, view in enumerate(trainer.train_views):
            by_camera.setdefault(camera_key(view, i), []).append(i)
        self.masks = {}
        for views in by_camera.values():
            if len(views) < MIN_FRAMES_FOR_CHANGE:
                continue
            images = [trainer._targets[i].detach().cpu().numpy() for i in views]
            if len({im.shape for im in images}) != 1:
                continue  # frames of one camera at different sizes: no per-pixel median
            for i, m in zip(views, changing_pixels(images)):
                self.masks[i] = torch.from_numpy(m).to(trainer.device)
        if self.masks:
            self.moving_share = float(np.mean([float(m.float().mean()) for m in self.masks.values()]))

    def loss_terms(self, ctx: StepContext) -> dict | None:
        mask = self.masks.get(ctx.view_index)
        if mask is None or self.weight == 0 or tuple(ctx.render.color.shape[:2]) != tuple(mask.shape):
            return None
        diff = (ctx.render.color - ctx.target).abs() * mask[..., None].to(ctx.render.color.dtype)
        return {"motion_l1": (self.weight, diff.mean())}

    def report(self) -> dict:
        return {"weight": self.weight, "views_with_motion": len(self.masks),
                "moving_share": round(self.moving_share, 4)}
