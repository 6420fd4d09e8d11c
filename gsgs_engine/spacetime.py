"""Spacetime Gaussians ("SpacetimeGS-lite", METHOD.md "4D"): 3D Gaussians with temporal parameters.

Each Gaussian adds a temporal centre mu_t, a temporal scale s_t (stored as log), cubic motion
coefficients b_1..b_3 and an angular velocity omega (quaternion units per unit time). At a time
t in [0, 1] it becomes an ordinary 3D Gaussian (`SpacetimeModel.at_time`), rendered by the same
rasteriser, so gradients reach the temporal parameters through plain autograd.

PLY fields added to the 3DGS layout (a 3D reader ignores them; `GaussianPly.extra` keeps them):
  t_center            mu_t, in the scene's normalised time [0, 1]
  t_scale             log s_t (natural log, like scale_0..2)
  motion_0..motion_8  b_1 (x, y, z), b_2 (x, y, z), b_3 (x, y, z): motion_{3(k-1)+axis}
  omega_0..omega_3    angular velocity (w, x, y, z), added to rot_0..3 per unit of (t - mu_t)
x y z / rot_* / opacity are the values at t = mu_t (position, rotation, peak opacity logit).
"""

from __future__ import annotations

import numpy as np
import torch

from gsgs_engine import GsgsError
from gsgs_engine.gaussians import GaussianModel, knn_mean_sq_dist

TEMPORAL_PARAM_NAMES = ("t_center", "t_log_scale", "motion", "omega")
MOTION_DEGREE = 3
PLY_T_CENTER = "t_center"
PLY_T_SCALE = "t_scale"
PLY_MOTION = tuple(f"motion_{i}" for i in range(3 * MOTION_DEGREE))
PLY_OMEGA = tuple(f"omega_{i}" for i in range(4))
PLY_TEMPORAL_FIELDS = (PLY_T_CENTER, PLY_T_SCALE) + PLY_MOTION + PLY_OMEGA


# -- the 4D equations (METHOD.md "4D", after SpacetimeGS) -------------------------------------------
def polynomial_position(means: torch.Tensor, motion: torch.Tensor, dt: torch.Tensor) -> torch.Tensor:
    """position(t) = mu + sum_{k=1..3} b_k (t - mu_t)^k  (METHOD.md 4D, motion). motion: [N, 3, 3] = b_k rows."""
    powers = torch.stack([dt ** k for k in range(1, motion.shape[1] + 1)], dim=1)  # [N, K]
    return means + (powers[:, :, None] * motion).sum(dim=1)


def rotation_at(quats: torch.Tensor, omega: torch.Tensor, dt: torch.Tensor) -> torch.Tensor:
    """rotation(t) = normalise(q + omega (t - mu_t))  (METHOD.md 4D, angular velocity)."""
    q = quats + omega * dt[:, None]
    return q / q.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def temporal_weight(t_center: torch.Tensor, t_scale: torch.Tensor, t: float | torch.Tensor) -> torch.Tensor:
    """exp(-((t - mu_t) / s_t)^2): the temporal radial basis, each Gaussian's share of its peak opacity at time t."""
    return torch.exp(-((t - t_center) / t_scale) ** 2)


def temporal_opacity(opacity_logits: torch.Tensor, t_center: torch.Tensor, t_scale: torch.Tensor,
                     t: float | torch.Tensor) -> torch.Tensor:
    """opacity(t) = sigmoid(o) * exp(-((t - mu_t) / s_t)^2)  (METHOD.md 4D, temporal radial basis)."""
    return torch.sigmoid(opacity_logits) * temporal_weight(t_center, t_scale, t)


class SpacetimeModel(GaussianModel):
    """GaussianModel plus the temporal parameters; `params` holds all of them (leaf tensors).

    The 3D properties (means, quats, opacities) are the values at each Gaussian's own
    temporal centre; `at_time(t)` gives what `render()` takes at time t.
    """

    def __init__(self, means, log_scales, quats, opacity_logits, sh_dc, sh_rest, max_sh_degree: int,
                 t_center, t_log_scale, motion=None, omega=None, active_sh_degree: int = 0):
        super().__init__(means, log_scales, quats, opacity_logits, sh_dc, sh_rest, max_sh_degree, active_sh_degree)
        n = self.num_gaussians
        motion = torch.zeros(n, MOTION_DEGREE, 3) if motion is None else motion
        omega = torch.zeros(n, 4) if omega is None else omega
        for name, value in zip(TEMPORAL_PARAM_NAMES, (t_center, t_log_scale, motion, omega)):
            self.params[name] = torch.as_tensor(value, dtype=torch.float32).detach().clone().requires_grad_(True)
        expect = {"t_center": (n,), "t_log_scale": (n,), "motion": (n, MOTION_DEGREE, 3), "omega": (n, 4)}
        for name, shape in expect.items():
            if tuple(self.params[name].shape) != shape:
                raise GsgsError(f"temporal parameter {name} has shape {tuple(self.params[name].shape)}, "
                                f"expected {shape}")

    # -- temporal activations ---------------------------------------------------------
    @property
    def t_center(self) -> torch.Tensor:
        return self.params["t_center"]

    @property
    def t_scale(self) -> torch.Tensor:
        return torch.exp(self.params["t_log_scale"])

    def at_time(self, t: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """(means, quats, scales, opacities) of the 3D Gaussians at time t (differentiable)."""
        if t is None or not np.isfinite(float(t)):
            raise GsgsError(f"a 4D model renders at a finite time; got {t!r} (the camera carries no time)")
        p = self.params
        dt = float(t) - p["t_center"]
        means = polynomial_position(p["means"], p["motion"], dt)
        quats = rotation_at(p["quats"], p["omega"], dt)
        opac = temporal_opacity(p["opacity_logits"], p["t_center"], self.t_scale, float(t))
        return means, quats, self.scales, opac

    # -- construction -------------------------------------------------------------------
    @classmethod
    def from_static(cls, model: GaussianModel, t_center, t_scale) -> "SpacetimeModel":
        """Temporal parameters around an existing 3D model: no motion or spin, centres/scales as given."""
        n = model.num_gaussians
        tc = torch.as_tensor(np.broadcast_to(np.asarray(t_center, dtype=np.float32), (n,)).copy())
        ts = torch.as_tensor(np.broadcast_to(np.asarray(t_scale, dtype=np.float32), (n,)).copy())
        if bool((ts <= 0).any()) or not bool(torch.isfinite(ts).all()):
            raise GsgsError("temporal scales must be positive and finite")
        p = model.params
        return cls(p["means"], p["log_scales"], p["quats"], p["opacity_logits"], p["sh_dc"], p["sh_rest"],
                   model.max_sh_degree, tc, torch.log(ts), active_sh_degree=model.active_sh_degree)

    @classmethod
    def from_points(cls, points: np.ndarray, colors: np.ndarray | None, max_sh_degree: int,
                    initial_opacity: float = 0.1, times: np.ndarray | None = None,
                    t_scale: float = 0.25) -> "SpacetimeModel":
        """3DGS initialisation from points seen across time: each point's time becomes its t_center.

        Points of different times are spaced with the k-NN of their own time's cloud, so a point
        cloud that repeats the same surface at every frame does not make tiny Gaussians.
        """
        if times is None:
            raise GsgsError("4D initialisation needs a time per point; a static point cloud makes a 3D model")
        times = np.asarray(times, dtype=np.float32).reshape(-1)
        pts = np.asarray(points, dtype=np.float32).reshape(-1, 3)
        if len(times) != len(pts):
            raise GsgsError(f"{len(pts)} points but {len(times)} times; give one time per point")
        base = GaussianModel.from_points(pts, colors, max_sh_degree, initial_opacity)
        log_scales = base.params["log_scales"].detach().clone()
        for value in np.unique(times):
            sel = torch.from_numpy(times == value)
            if int(sel.sum()) > 1:
                d2 = knn_mean_sq_dist(torch.from_numpy(pts[times == value])).clamp_min(1e-7)
                log_scales[sel] = torch.log(torch.sqrt(d2))[:, None].repeat(1, 3)
        with torch.no_grad():
            base.params["log_scales"].copy_(log_scales)
        return cls.from_static(base, times, t_scale)

    # -- (de)serialisation ----------------------------------------------------------------
    def state_dict(self) -> dict:
        state = super().state_dict()
        state["spacetime"] = True
        return state

    @classmethod
    def from_state_dict(cls, state: dict) -> "SpacetimeModel":
        p = state["params"]
        return cls(p["means"], p["log_scales"], p["quats"], p["opacity_logits"], p["sh_dc"], p["sh_rest"],
                   state["max_sh_degree"], p["t_center"], p["t_log_scale"], p["motion"], p["omega"],
                   active_sh_degree=state["active_sh_degree"])

    def to_ply(self):
        ply = super().to_ply()
        p = {k: self.params[k].detach().cpu().numpy().astype(np.float32) for k in TEMPORAL_PARAM_NAMES}
        extra = {PLY_T_CENTER: p["t_center"], PLY_T_SCALE: p["t_log_scale"]}
        motion = p["motion"].reshape(-1, 3 * MOTION_DEGREE)
        extra.update({name: motion[:, i].copy() for i, name in enumerate(PLY_MOTION)})
        extra.update({name: p["omega"][:, i].copy() for i, name in enumerate(PLY_OMEGA)})
        ply.extra = {**ply.extra, **extra}
        return ply

    @classmethod
    def from_ply(cls, ply) -> "SpacetimeModel":
        if not is_spacetime_ply(ply):
            missing = [f for f in PLY_TEMPORAL_FIELDS if f not in (ply.extra or {})]
            raise GsgsError(f"this PLY has no temporal fields ({', '.join(missing[:3])}...); it is a 3D model, "
                            "load it with GaussianModel.from_ply")
        static = GaussianModel.from_ply(ply)
        ex = ply.extra
        n = static.num_gaussians
        motion = np.stack([np.asarray(ex[f], dtype=np.float32) for f in PLY_MOTION], axis=1)
        motion = motion.reshape(n, MOTION_DEGREE, 3)
        omega = np.stack([np.asarray(ex[f], dtype=np.float32) for f in PLY_OMEGA], axis=1)
        p = static.params
        return cls(p["means"], p["log_scales"], p["quats"], p["opacity_logits"], p["sh_dc"], p["sh_rest"],
                   static.max_sh_degree, np.asarray(ex[PLY_T_CENTER], dtype=np.float32),
                   np.asarray(ex[PLY_T_SCALE], dtype=np.float32), motion, omega,
                   active_sh_degree=static.active_sh_degree)


def is_spacetime_ply(ply) -> bool:
    """True when a GaussianPly carries every temporal field of this module."""
    extra = getattr(ply, "extra", None) or {}
    return all(f in extra for f in PLY_TEMPORAL_FIELDS)


def model_from_ply(ply) -> GaussianModel:
    """A SpacetimeModel when the PLY has temporal fields, else a plain 3D GaussianModel."""
    return SpacetimeModel.from_ply(ply) if is_spacetime_ply(ply) else GaussianModel.from_ply(ply)


def gaussians_at(model: GaussianModel, t: float | None):
    """(means, quats, scales, opacities) for rendering: a 3D model ignores t, a 4D one needs it."""
    if isinstance(model, SpacetimeModel):
        return model.at_time(t)
    return model.means, model.quats, model.scales, model.opacities


def render_at(model: GaussianModel, camera, background: torch.Tensor, backend: str = "auto",
              sh_degree: int | None = None, time: float | None = None, near: float | None = None):
    """Render `model` from `camera` at `time` (default camera.time) through gsgs_engine.render.render();
    `near`: the near plane (None: the renderer's default; an inward shell's novel views use the run's)."""
    from gsgs_engine.render import render

    t = camera.time if time is None else time
    degree = model.active_sh_degree if sh_degree is None else sh_degree
    means, quats, scales, opac = gaussians_at(model, t)
    extra = {} if near is None else {"near": float(near)}
    return render(means, quats, scales, opac, model.sh(degree), camera, sh_degree=degree,
                  background=background, backend=backend, **extra)
