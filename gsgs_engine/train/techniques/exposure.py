"""Per-camera exposure and white balance, learned beside the scene.

Photos of one scene rarely share an exposure: phones meter each shot, and the cameras of a capture rig
(CMU Panoptic's dome, a few synchronised GoPros) differ visibly in gain and white balance. A model that
must reproduce every photo's colours exactly explains those differences with geometry: view-dependent
colour, or Gaussians floating in front of one camera that tint only its view. Here every training camera
gets a colour gain and offset per channel,

    photo ~ gain_c * render + offset_c        (gain_c = exp(log_gain_c), per camera c, per channel),

learned with their own Adam while the scene trains (the idea of the per-camera colour scale and offset of
Dynamic 3D Gaussians and of NeRF-W-style appearance codes, reduced to the affine part). The scene keeps the
colours of the average camera: after each step the log gains and the offsets are re-centred to mean zero
over the cameras, so novel views (test cameras, pseudo views, the exported PLY) need no correction and get
none: `Trainer.render` draws the model as it is.

The correction is applied to the Gaussians' colours in `render_inputs` rather than to the image: the
compositing is linear in colour, so for a view the Gaussians cover (alpha = 1) the two are the same, and
the SH coefficients stay the one colour representation (DC: gain * (C0 dc + 0.5) + offset - 0.5 over C0;
the view-dependent bands scale by the gain).

Which camera a render is supervised by: the step's training view, or the view a technique names in
`ctx.shared[PHOTO_VIEW]` for its own render (a pseudo view warped from a training photo names that photo's
view). Views of one physical camera share one correction: `Camera.extra["camera_index"]` where the loader
sets it (multi-view video: every frame of a camera), otherwise each training view is its own camera.
"""

from __future__ import annotations

import torch

from gsgs_engine import GsgsError
from gsgs_engine.render.sh import SH_C0
from gsgs_engine.train.technique import PHOTO_VIEW, StepContext, Technique, joined_sh

DEFAULT_LR = 1e-3


def camera_key(view, index: int):
    """The physical camera a training view was taken with (its index among views when the loader did not say)."""
    extra = getattr(view.camera, "extra", None) or {}
    return ("camera", int(extra["camera_index"])) if "camera_index" in extra else ("view", index)


def corrected_sh(sh: torch.Tensor, gain: torch.Tensor, offset: torch.Tensor) -> torch.Tensor:
    """SH coefficients [N, K, 3] whose colour is gain * colour + offset (colour = C0 dc + rest + 0.5)."""
    dc = gain * sh[:, :1] + (gain * 0.5 + offset - 0.5) / SH_C0
    return torch.cat([dc, gain * sh[:, 1:]], dim=1) if sh.shape[1] > 1 else dc


class ExposureCompensation(Technique):
    name = "exposure"

    def __init__(self, lr: float = DEFAULT_LR):
        if not (lr > 0.0 and lr < 1.0):
            raise GsgsError(f"exposure: the learning rate must be in (0, 1) (got {lr})")
        self.lr = float(lr)
        self.keys: list = []
        self.group_of_view: list[int] = []
        self.log_gain: torch.Tensor | None = None
        self.offset: torch.Tensor | None = None
        self.optimizer: torch.optim.Optimizer | None = None

    def install(self, trainer) -> None:
        keys = [camera_key(v, i) for i, v in enumerate(trainer.train_views)]
        self.keys = sorted(set(keys))
        index = {k: g for g, k in enumerate(self.keys)}
        self.group_of_view = [index[k] for k in keys]
        device = trainer.device
        self.log_gain = torch.zeros(len(self.keys), 3, device=device, requires_grad=True)
        self.offset = torch.zeros(len(self.keys), 3, device=device, requires_grad=True)
        self.optimizer = torch.optim.Adam([self.log_gain, self.offset], lr=self.lr, eps=1e-15)

    def before_step(self, trainer, step: int) -> None:
        self.optimizer.zero_grad(set_to_none=True)  # a skipped (non-finite) step leaves nothing behind

    def render_inputs(self, ctx: StepContext, inputs: dict) -> dict:
        if len(self.keys) < 2:  # one camera: re-centred, its correction is the identity
            return inputs
        g = self.group_of_view[int(ctx.shared.get(PHOTO_VIEW, ctx.view_index))]
        inputs = joined_sh(inputs)
        gain = torch.exp(self.log_gain[g]).to(inputs["sh"].dtype)
        return {**inputs, "sh": corrected_sh(inputs["sh"], gain, self.offset[g].to(inputs["sh"].dtype))}

    def after_step(self, trainer, step: int) -> None:
        if len(self.keys) < 2:
            return
        grads = [p.grad for p in (self.log_gain, self.offset) if p.grad is not None]
        if grads and all(bool(torch.isfinite(gr).all()) for gr in grads):
            self.optimizer.step()
        self.optimizer.zero_grad(set_to_none=True)
        with torch.no_grad():  # the scene keeps the average camera's colours
            self.log_gain -= self.log_gain.mean(dim=0, keepdim=True)
            self.offset -= self.offset.mean(dim=0, keepdim=True)

    def state_dict(self) -> dict:
        return {"keys": [list(k) for k in self.keys], "log_gain": self.log_gain.detach().cpu(),
                "offset": self.offset.detach().cpu(), "optimizer": self.optimizer.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        if [tuple(k) for k in state.get("keys", [])] != self.keys:
            raise GsgsError("exposure: the checkpoint's cameras differ from this run's training cameras; "
                            "resume with the same training views (or start again)")
        with torch.no_grad():
            self.log_gain.copy_(state["log_gain"].to(self.log_gain.device))
            self.offset.copy_(state["offset"].to(self.offset.device))
        self.optimizer.load_state_dict(state["optimizer"])

    def report(self) -> dict:
        gains = torch.exp(self.log_gain.detach()).cpu()
        offsets = self.offset.detach().cpu()
        return {"lr": self.lr, "cameras": len(self.keys),
                "gain_range": [round(float(gains.min()), 4), round(float(gains.max()), 4)],
                "offset_range": [round(float(offsets.min()), 4), round(float(offsets.max()), 4)],
                "per_camera": {f"{kind} {k}": {"gain": [round(float(x), 4) for x in gains[g]],
                                               "offset": [round(float(x), 4) for x in offsets[g]]}
                               for g, (kind, k) in enumerate(self.keys)}}
