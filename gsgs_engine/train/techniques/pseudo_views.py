"""Supervised pseudo views (eq. 11's pseudo terms): extra cameras with target images.

Every `every` steps one pseudo view, drawn at random, is rendered and compared with its
target (L1 + D-SSIM, weighted by the view's weight, optionally masked). With `scale` < 1 the
view is rendered at that fraction of its size and compared with its target and mask
area-averaged to the same size, once per round (`resize_area`): a pseudo target is a
warp-inpainted or generated image whose detail the loss does not need at full resolution. The GS-GS prior loop
replaces the views between rounds (`set_views`); anything else may too (a test, a script,
artist-authored targets).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera
from gsgs_engine.train.losses import photometric_terms
from gsgs_engine.train.resample import resize_area
from gsgs_engine.train.technique import PHOTO_VIEW, StepContext, Technique


@dataclass
class PseudoView:
    """An extra supervised view: a camera, a target image [H, W, 3] in [0, 1] and a loss weight."""

    camera: Camera
    image: np.ndarray | torch.Tensor
    weight: float = 1.0
    name: str = ""
    nearest_train: int | None = None  # index into the trainer's training views
    mask: np.ndarray | torch.Tensor | None = None  # (H, W): the pixels the target is trusted on (None: all)
    extra: dict = field(default_factory=dict)


def _as_image_tensor(img) -> torch.Tensor:
    t = torch.as_tensor(np.asarray(img, dtype=np.float32) if not torch.is_tensor(img) else img).float()
    if t.ndim != 3 or t.shape[2] != 3:
        raise GsgsError(f"a target image must be H x W x 3, got shape {tuple(t.shape)}")
    return t


class PseudoSupervision(Technique):
    """Renders one pseudo view every `every` steps and adds its photometric terms ("pseudo_l1", "pseudo_dssim")."""

    name = "pseudo_views"

    def __init__(self, views: list[PseudoView] | None = None, every: int = 1, scale: float = 1.0):
        self.every = max(int(every), 1)
        if not 0.0 < scale <= 1.0:
            raise GsgsError(f"pseudo views: the render scale must be in (0, 1] (got {scale})")
        self.scale = float(scale)
        self._cameras: list[Camera] = []
        self.views: list[PseudoView] = []
        self._targets: list[torch.Tensor] = []
        self._masks: list[torch.Tensor | None] = []
        self._pending = list(views or [])
        self.trainer = None

    def install(self, trainer) -> None:
        self.trainer = trainer
        if self._pending:
            self.set_views(self._pending)
            self._pending = []

    def set_views(self, views: list[PseudoView]) -> None:
        """Replace all pseudo views (called between rounds of Alg. 1)."""
        device = self.trainer.device
        targets = []
        for pv in views:
            t = _as_image_tensor(pv.image)
            if (t.shape[1], t.shape[0]) != (pv.camera.width, pv.camera.height):
                raise GsgsError(f"pseudo view {pv.name!r}: image is {t.shape[1]}x{t.shape[0]} but its camera is "
                                f"{pv.camera.width}x{pv.camera.height}")
            targets.append(t.to(device))
            if pv.mask is not None and tuple(pv.mask.shape) != tuple(t.shape[:2]):
                raise GsgsError(f"pseudo view {pv.name!r}: mask is {tuple(pv.mask.shape)}, image {tuple(t.shape[:2])}")
        self.views = list(views)
        self._cameras = [pv.camera if self.scale == 1.0 else pv.camera.scaled(self.scale) for pv in views]
        self._targets = [resize_area(t, c.height, c.width) for t, c in zip(targets, self._cameras)]
        self._masks = [None if pv.mask is None else
                       resize_area(torch.as_tensor(pv.mask).to(device, torch.float32), c.height, c.width)
                       for pv, c in zip(views, self._cameras)]

    def loss_terms(self, ctx: StepContext) -> dict | None:
        if not self.views or ctx.step % self.every != 0:
            return None
        tr = ctx.trainer
        j = int(tr.np_rng.integers(len(self.views)))
        pv, camera = self.views[j], self._cameras[j]
        if pv.nearest_train is not None:  # the photo its target was warped from (per-camera exposure)
            ctx.shared[PHOTO_VIEW] = int(pv.nearest_train)
        try:
            out = tr.render_for_training(ctx, camera)  # a pseudo target has the scene background baked in
        finally:
            ctx.shared.pop(PHOTO_VIEW, None)
        ctx.renders.append((out, camera))
        ctx.shared["pseudo"] = (j, pv, out)
        return photometric_terms(out.color, self._targets[j], tr.config.lambda_dssim, weight=pv.weight,
                                 prefix="pseudo_", mask=self._masks[j])

    def report(self) -> dict:
        return {"views": len(self.views), "every": self.every, "scale": self.scale}
