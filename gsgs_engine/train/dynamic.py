"""4D training: the Trainer's loop on a SpacetimeModel (gsgs_engine.spacetime).

What changes against 3D: every view (training or pseudo) renders at its camera's time; the
Gaussians start from points triangulated per frame (each point's frame time is its temporal
centre) or at random in space and time; densification clones and splits every parameter,
temporal ones included, and prunes Gaussians that are faint at every time in [0, 1]. The
base Trainer's 3D densification is switched off for the step and this one runs instead.
Only a scene with time makes a 4D model (`make_trainer` picks).
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from gsgs_engine import GsgsError
from gsgs_engine.gaussians import GaussianModel, InitInfo, scene_bounds_from_cameras
from gsgs_engine.spacetime import SpacetimeModel, gaussians_at
from gsgs_engine.train import checkpoint as ckpt
from gsgs_engine.train.densify import (DensifyConfig, DensifyStats, _replace_param, clone_and_split_rows,
                                       reset_opacity)
from gsgs_engine.train.trainer import TrainConfig, Trainer

# Temporal learning rates (Adam), chosen for time in [0, 1]: a temporal centre can travel across a
# 10-frame clip within a few hundred steps; motion is in world units per unit time, so it scales
# with the scene extent like positions do.
T_CENTER_LR = 1e-3
T_SCALE_LR = 1e-2
MOTION_LR = 1.6e-3  # x scene extent
OMEGA_LR = 1e-3
INIT_T_SCALE_FRAMES = 2.0  # initial temporal scale = this many frame spacings
RANDOM_INIT_T_SCALE = 0.25


def views_by_frame(views) -> dict[float, list]:
    """Training views grouped by time (one group per frame), in time order."""
    groups: dict[float, list] = {}
    for v in views:
        if v.camera.time is None:
            raise GsgsError(f"view {v.name!r} has no time; a 4D model trains on views that all carry a time")
        groups.setdefault(float(v.camera.time), []).append(v)
    return dict(sorted(groups.items()))


def initialise_spacetime(scene, train_views, config: TrainConfig, generator: torch.Generator,
                         log: Callable[[str], None] = print) -> tuple[SpacetimeModel, InitInfo]:
    """Points triangulated per frame with known poses (time = the frame's), else random in space-time."""
    frames = views_by_frame(train_views)
    times = list(frames)
    spacing = float(np.min(np.diff(times))) if len(times) > 1 else 1.0
    t_scale = max(INIT_T_SCALE_FRAMES * spacing, 1e-3)
    reasons = []
    if config.init == "mvs":
        return _per_frame_mvs(scene, frames, config, t_scale, log)
    if config.init in ("auto", "sfm"):
        pts_all, cols_all, t_all = [], [], []
        try:
            from gsgs_engine.sfm import triangulate_known_poses
        except ImportError as exc:
            reasons.append(f"triangulation unavailable ({exc})")
        else:
            for t, views in frames.items():
                if len(views) < 2:
                    continue
                try:
                    pts, cols = triangulate_known_poses(views)
                except GsgsError as exc:
                    reasons.append(f"frame t={t:.3f}: {exc}")
                    continue
                pts = np.asarray(pts, dtype=np.float32).reshape(-1, 3)
                pts_all.append(pts)
                cols_all.append(np.asarray(cols, dtype=np.float32).reshape(-1, 3))
                t_all.append(np.full(len(pts), t, dtype=np.float32))
        n = int(sum(len(p) for p in pts_all))
        if n >= config.min_init_points:
            model = SpacetimeModel.from_points(np.concatenate(pts_all), np.concatenate(cols_all), config.sh_degree,
                                               times=np.concatenate(t_all), t_scale=t_scale)
            return model, InitInfo("sfm", n, f"{n} points triangulated per frame over {len(frames)} frames "
                                              f"(temporal centre = the frame's time, scale {t_scale:.3f})")
        reasons.append(f"per-frame triangulation gave {n} points (< {config.min_init_points})")
    if config.init not in ("auto", "sfm", "random"):
        raise GsgsError(f"init {config.init!r} is not available for 4D; use auto, sfm or random")
    lo, hi = scene_bounds_from_cameras([v.camera for v in train_views], scene.near, scene.far)
    base = GaussianModel.random_in_box(lo, hi, config.random_init_points, config.sh_degree, generator=generator)
    t_center = torch.rand(config.random_init_points, generator=generator).numpy()
    model = SpacetimeModel.from_static(base, t_center, RANDOM_INIT_T_SCALE)
    why = "; ".join(reasons) if reasons else "requested"
    return model, InitInfo("random", config.random_init_points,
                           f"random in the box {np.round(lo, 3).tolist()}..{np.round(hi, 3).tolist()} and uniform "
                           f"in time, temporal scale {RANDOM_INIT_T_SCALE} ({why})")


def _per_frame_mvs(scene, frames: dict, config: TrainConfig, t_scale: float, log) -> tuple[SpacetimeModel, InitInfo]:
    """Dense multi-view-stereo points of every frame's training views (plus that frame's SfM points), each at
    its frame's time: the static init's plane sweep (gsgs_engine.init.mvs), run per frame. The point budget
    and the fallback are shared out over the frames, so a clip starts no larger than a still would."""
    from dataclasses import replace

    from gsgs_engine.init.mvs import MVSConfig, dense_and_sparse_points, mvs_flow_method

    base = MVSConfig(max_side=config.mvs_max_side, flow=mvs_flow_method(config.mvs_flow))
    per_frame = replace(base, max_points=max(base.max_points // len(frames), 1000),
                        min_points=max(base.min_points // len(frames), 100),
                        fallback_points=max(base.fallback_points // len(frames), 500))
    pts_all, cols_all, t_all, methods = [], [], [], []
    quiet = lambda msg: None  # noqa: E731 - one line per frame below instead of one per view
    for k, (t, views) in enumerate(frames.items()):
        pts, cols, method, _ = dense_and_sparse_points(scene, views, seed=config.seed + k, config=per_frame,
                                                        log=quiet)
        pts_all.append(np.asarray(pts, np.float32))
        cols_all.append(np.asarray(cols, np.float32))
        t_all.append(np.full(len(pts), t, dtype=np.float32))
        methods.append(method)
        log(f"4D init: frame t={t:.3f}: {len(pts)} points ({method}, {len(views)} views)")
    n = int(sum(len(p) for p in pts_all))
    model = SpacetimeModel.from_points(np.concatenate(pts_all), np.concatenate(cols_all), config.sh_degree,
                                       times=np.concatenate(t_all), t_scale=t_scale)
    kinds = ", ".join(f"{m} x{methods.count(m)}" for m in sorted(set(methods)))
    return model, InitInfo("mvs", n, f"{n} multi-view-stereo + SfM points, per frame over {len(frames)} frames "
                                     f"({kinds}; temporal centre = the frame's time, scale {t_scale:.3f})")


# -- densification that respects time -----------------------------------------------------------
def peak_opacity_in_clip(model: SpacetimeModel) -> torch.Tensor:
    """max over t in [0, 1] of opacity(t): the opacity at the clip time nearest each temporal centre."""
    p = model.params
    nearest = p["t_center"].detach().clamp(0.0, 1.0)
    dist = (nearest - p["t_center"].detach()) / model.t_scale.detach()
    return torch.sigmoid(p["opacity_logits"].detach()) * torch.exp(-dist ** 2)


def _set_rows(model, optimizer, new: dict[str, torch.Tensor] | None, keep: torch.Tensor | None) -> None:
    """Append rows (zero Adam moments) or keep a subset, for EVERY parameter, temporal ones included."""
    for name in list(model.params):
        if new is not None:
            extra = new[name].detach()
            _replace_param(model, optimizer, name, torch.cat([model.params[name].detach(), extra], dim=0),
                           lambda s, extra=extra: torch.cat([s, torch.zeros_like(extra)], dim=0))
        else:
            _replace_param(model, optimizer, name, model.params[name].detach()[keep], lambda s: s[keep])


def densify_and_prune_4d(model: SpacetimeModel, optimizer: torch.optim.Optimizer, stats: DensifyStats,
                         extent: float, config: DensifyConfig, prune_large: bool,
                         generator: torch.Generator | None = None, size_extent: float | None = None) -> dict:
    """3DGS clone / split on the mean screen-space gradient, carrying the temporal parameters along.

    Clones copy every parameter. Splits sample new centres inside the parent's 3D Gaussian (at its
    temporal centre) and keep its temporal centre, temporal scale, motion and angular velocity, so
    both children follow the parent's trajectory. Pruning uses the peak opacity within the clip.
    """
    n = model.num_gaussians
    with torch.no_grad():
        new, clone_mask, split_mask = clone_and_split_rows(model, stats, extent, config, generator)
    _set_rows(model, optimizer, new, None)
    with torch.no_grad():
        n_new = new["means"].shape[0]
        prune = torch.cat([split_mask, torch.zeros(n_new, dtype=torch.bool, device=split_mask.device)])
        prune |= peak_opacity_in_clip(model) < config.min_opacity
        if prune_large:
            prune |= model.scales.detach().max(dim=1).values > config.max_world_size * (size_extent or extent)
        if bool(prune.all()):
            prune[torch.argmax(model.opacities.detach())] = False
    _set_rows(model, optimizer, None, ~prune)
    stats.reset(model.num_gaussians)
    return {"cloned": int(clone_mask.sum()), "split": int(split_mask.sum()), "pruned": int(prune.sum()),
            "num_gaussians": model.num_gaussians, "before": n, "total_before_prune": n + n_new}


class SpacetimeTrainer(Trainer):
    """Trainer for scenes with time: same loop, losses, hooks and checkpoints, on a SpacetimeModel."""

    def __init__(self, scene, config: TrainConfig, *args, **kwargs):
        if not scene.has_time:
            raise GsgsError(f"{scene.source}: the views carry no time, so there is nothing 4D to learn; "
                            "train a 3D model (gsgs train) instead")
        super().__init__(scene, config, *args, **kwargs)
        views_by_frame(self.train_views)  # every training view must carry a time
        self._pending_state: dict | None = None
        self._densify = bool(config.densify)  # what the step densifies by (the base loop's is off during a step)

    # -- model, optimiser, rendering ------------------------------------------------------------
    def setup(self, resume: bool = False, initial_model: GaussianModel | None = None,
              init_info: InitInfo | None = None) -> None:
        if initial_model is not None and not isinstance(initial_model, SpacetimeModel):
            raise GsgsError("a 4D trainer continues only from a 4D model (SpacetimeModel)")
        resuming = resume and self.checkpoint_dir and ckpt.latest_checkpoint(self.checkpoint_dir) is not None
        if initial_model is None and not resuming:
            t0 = time.perf_counter()
            model, info = initialise_spacetime(self.scene, self.train_views, self.config, self.torch_gen, self.log)
            self.phase_seconds["init"] += time.perf_counter() - t0
            log, self.log = self.log, (lambda msg: None)  # the base would call this model "given"
            try:
                super().setup(resume=False, initial_model=model)
            finally:
                self.log = log
            self.init_info = info
            self.log(f"4D init: {info.method}, {info.num_points} Gaussians ({info.reason})")
            return
        super().setup(resume=resume, initial_model=initial_model, init_info=init_info)

    def _make_optimizer(self) -> torch.optim.Optimizer:
        if not isinstance(self.model, SpacetimeModel):
            # Trainer._load rebuilds a 3D model from the checkpoint; the 4D one is in the same state dict.
            if self._pending_state is None:
                raise GsgsError("internal: a 4D trainer got a 3D model")
            self.model = SpacetimeModel.from_state_dict(self._pending_state["model"]).to(self.device)
        opt = super()._make_optimizer()
        p = self.model.params
        for name, lr in (("t_center", T_CENTER_LR), ("t_log_scale", T_SCALE_LR),
                         ("motion", MOTION_LR * self.extent), ("omega", OMEGA_LR)):
            opt.add_param_group({"params": [p[name]], "lr": lr, "name": name})
        return opt

    def _load(self, path: Path) -> None:
        self._pending_state = ckpt.load_checkpoint(path)
        if not self._pending_state.get("model", {}).get("spacetime"):
            raise GsgsError(f"{path}: this checkpoint holds a 3D model; resume it with the 3D trainer")
        try:
            super()._load(path)
        finally:
            self._pending_state = None

    def gaussians_for(self, camera, sh_degree: int | None = None) -> dict:
        """The model at camera.time (training, pseudo and test views alike); see spacetime.render_at."""
        degree = self.model.active_sh_degree if sh_degree is None else sh_degree
        means, quats, scales, opacities = gaussians_at(self.model, camera.time)
        return {"means": means, "quats": quats, "scales": scales, "opacities": opacities,
                "sh": self.model.sh(degree), "sh_degree": degree}

    # -- the step: base loop without its 3D densification, then the 4D one ---------------------------
    def gathers_densify_statistics(self, step: int) -> bool:
        return self._densify and step <= self.schedule.densify_until

    def train_step(self) -> bool:
        cfg, sched = self.config, self.schedule
        step = self.step + 1
        densify = self._densify = cfg.densify
        cfg.densify = False  # the base loop's densification handles only 3D parameters
        try:
            ok = super().train_step()
        finally:
            cfg.densify = densify
        renders = self.last_step_renders
        if not (ok and densify and step <= sched.densify_until):
            return ok
        t0 = time.perf_counter()
        for r, cam in renders:
            self.stats.accumulate(self.densify_gradient(r), r.radii.detach(), cam.width, cam.height)
        if sched.is_densify_step(step):
            info = densify_and_prune_4d(self.model, self.optimizer, self.stats, self.extent, cfg.densify_config,
                                        prune_large=step > sched.opacity_reset_every, generator=self.torch_gen,
                                        size_extent=self.size_extent)
            info["step"] = step
            self.densify_log.append(info)
        white = bool(torch.all(self.background == 1.0))
        if sched.is_opacity_reset_step(step) or (white and sched.white_reset_step(step)):
            reset_opacity(self.model, self.optimizer)
        self.phase_seconds["densify"] += time.perf_counter() - t0
        return ok


def make_trainer(scene, config: TrainConfig, **kwargs) -> Trainer:
    """A 4D trainer when the scene has time, else the plain 3D one (a static scene never gets temporal params)."""
    return SpacetimeTrainer(scene, config, **kwargs) if scene.has_time else Trainer(scene, config, **kwargs)


def spacetime_pseudo_views(train_views, per_time: int, times=None, jitter: float = 0.0, seed: int = 0) -> list:
    """Pseudo views at (pose, time) pairs for the prior loop (METHOD.md 4D: "pseudo poses at sampled times").

    For each time (default: every training frame) the poses are interpolated between that
    frame's training cameras; each pseudo view's `nearest_train` indexes `train_views` at the
    frame nearest its time, so a generator that warps the nearest training photo warps one
    taken at the same moment.
    """
    from gsgs_engine.priors.poses import PseudoView as PosePseudoView
    from gsgs_engine.priors.poses import interpolated_pseudo_views

    frames = views_by_frame(train_views)
    frame_times = np.array(list(frames))
    index = {id(v): i for i, v in enumerate(train_views)}
    wanted = frame_times if times is None else np.asarray(times, dtype=np.float64).reshape(-1)
    out = []
    for k, t in enumerate(wanted):
        if not (0.0 <= float(t) <= 1.0):
            raise GsgsError(f"pseudo view time {t} is outside the clip's [0, 1]")
        at = frames[float(frame_times[np.argmin(np.abs(frame_times - t))])]
        made = interpolated_pseudo_views([v.camera for v in at], per_time, jitter, seed + k, time=float(t))
        for p in made:
            cam = replace(p.camera, name=f"pseudo_t{float(t):.3f}_{len(out):03d}")
            out.append(PosePseudoView(cam, index[id(at[p.nearest_train])], p.source))
    return out
