"""3DGS optimisation: the step loop, NaN safety, densification, checkpoints and signals.

The trainer knows optimisation only. Sparse-view techniques (pseudo views, the GS-GS prior
loop, the depth regulariser, ...) take part through `gsgs_engine.train.technique.Technique`,
added with `Trainer.add_technique`; the trainer names none of them. `Trainer.train(until=k)`
trains up to step k. Orchestration (effect plan, initialisation, techniques, export,
evaluation) is `gsgs_engine.reconstruct`.
"""

from __future__ import annotations

import signal
import threading
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

from gsgs_engine import GsgsError
from gsgs_engine.init.mvs import MVSConfig
from gsgs_engine.cameras import Camera
from gsgs_engine.gaussians import GaussianModel, InitInfo, scene_bounds_from_cameras
from gsgs_engine.render.project import DEFAULT_NEAR
from gsgs_engine.train import checkpoint as ckpt
from gsgs_engine.train.densify import DensifyConfig, DensifyStats, densify_and_prune, reset_opacity
from gsgs_engine.train.losses import photometric_terms, total_loss
from gsgs_engine.train.nan_guard import check_skipped, grads_finite, nonfinite_cause
from gsgs_engine.train.technique import StepContext, Technique
from gsgs_engine.train.schedule import LearningRates, Schedule, position_lr

# Measured on lego_200 (8 views, 200 px, cpu backend, SfM init, effect plan) on the shared 2-core
# dev machine with the compiled projection / SSIM (issue 17): 1000 steps took 40 s of training and
# reached test PSNR 22.62-22.68 / SSIM 0.858 (seeds 0, 1). Well inside the 10-minute budget.
DEFAULT_ITERS = 1000
CHECKPOINT_FORMAT = 2  # 2: safetensors + JSON (1 was a pickle, never loaded)


@dataclass
class TrainConfig:
    iters: int = DEFAULT_ITERS
    sh_degree: int = 3
    backend: str = "auto"
    seed: int = 0
    checkpoint_every: int = 500
    lambda_dssim: float = 0.2
    random_background: bool = False
    init: str = "auto"  # auto | sfm | points | random
    min_init_points: int = 100
    random_init_points: int = 5000
    mvs_max_side: int = MVSConfig.max_side  # init "mvs": working size of the plane sweep (longest side, px)
    mvs_flow: str = "off"  # init "mvs": optical-flow matches fused with the stereo points ("off", "dis", "deepflow")
    densify: bool = True
    # coarse-to-fine (the idea of DashGaussian): the first `coarse_fraction` of the steps render the training
    # view at `coarse_scale` of its size against its area-averaged photo; 0 = full resolution throughout
    coarse_fraction: float = 0.0
    coarse_scale: float = 0.5
    # the near plane (world units) of renders from cameras other than a training step's own: evaluation,
    # pseudo views, `gsgs eval`. Gaussians closer to the camera are not drawn. The renderer's default; the
    # effect plan raises it on an inward-shell rig (gsgs_engine.effect_plan.NEAR_FRACTION), where a novel
    # camera sits inside the wall that the cameras opposite reconstructed. Training renders keep the
    # default: a training camera's photo already fits whatever lies before it (measured, panoptic 9
    # cameras, 1000 steps: the near plane in training too gave 14.89 / 14.17 dB plain / auto, against
    # 15.04 / 15.34 with it at evaluation only)
    novel_view_near: float = DEFAULT_NEAR
    # the means' learning rate as a multiple of 3DGS's schedule (LearningRates.position_*, decayed over the run);
    # None: the effect plan's choice (gsgs_engine.effect_plan: the recipe of the rig), 1.0 without a plan
    position_lr_scale: float | None = None
    # the colour (SH), scale and rotation learning rates as one multiple of 3DGS's (opacities and positions apart);
    # None: the effect plan's choice (the object-orbit recipe's, gsgs_engine.effect_plan.ATTRIBUTE_LR_SCALE), 1.0
    # without a plan
    attribute_lr_scale: float | None = None
    # a textured sphere through the cameras behind the splats (gsgs_engine.train.background_sphere): its texture's
    # width in texels (height half), 0 = the constant background; the effect plan's "sphere" background
    background_sphere: int = 0
    lr: LearningRates = field(default_factory=LearningRates)
    densify_config: DensifyConfig = field(default_factory=DensifyConfig)

    def to_dict(self) -> dict:
        return asdict(self)

    def attribute_rates(self) -> LearningRates:
        """`lr` with the colour, scale and rotation rates times `attribute_lr_scale` (None: 1)."""
        k = 1.0 if self.attribute_lr_scale is None else float(self.attribute_lr_scale)
        lr = self.lr
        return replace(lr, sh_dc=lr.sh_dc * k, sh_rest=lr.sh_rest * k, scaling=lr.scaling * k,
                       rotation=lr.rotation * k)

    @classmethod
    def from_dict(cls, d: dict) -> "TrainConfig":
        d = dict(d)
        lr = LearningRates(**d.pop("lr", {}))
        dc = DensifyConfig(**d.pop("densify_config", {}))
        known = {k: v for k, v in d.items() if k in cls.__dataclass_fields__}
        return cls(lr=lr, densify_config=dc, **known)


def _kernel_clock() -> dict[str, float] | None:
    from gsgs_engine.render import cpu_backend

    return cpu_backend.phase_seconds()


class TrainingInterrupted(KeyboardInterrupt):
    """SIGINT / SIGTERM arrived: the current step finished and a checkpoint was written."""

    def __init__(self, signum: int, step: int, checkpoint: Path | None):
        self.signum = signum
        self.step = step
        self.checkpoint = checkpoint
        super().__init__(f"interrupted by signal {signum} at step {step}")

    @property
    def exit_code(self) -> int:
        return 128 + int(self.signum)


class TrainingCancelled(Exception):
    """The job folder asked to cancel; a checkpoint was written."""

    def __init__(self, step: int, checkpoint: Path | None):
        self.step = step
        self.checkpoint = checkpoint
        super().__init__(f"cancelled at step {step}")


def resolve_device(backend: str) -> tuple[torch.device, str]:
    """(device the training tensors live on, its description for metrics.json's plan).

    "cuda" for backend "cuda", or "auto" where CUDA and gsplat both work; otherwise the CPU.
    An explicit "cuda" that cannot run stops here, before any data is loaded, saying what is
    missing and how to fix it.
    """
    from gsgs_engine.render import api

    if backend in ("cuda", "auto"):
        ok, reason = api.cuda_status()
        if ok:
            device = torch.device("cuda", torch.cuda.current_device())
            return device, f"{device} ({torch.cuda.get_device_name(device)})"
        if backend == "cuda":
            raise GsgsError(f"--backend cuda cannot run here: {reason}. Fix: run on a machine with an NVIDIA GPU, "
                            "a CUDA build of torch and gsplat installed (pip install gsplat), or leave the backend "
                            "to --backend auto (which uses the CPU here)")
    return torch.device("cpu"), "cpu"


def render_model(model: GaussianModel, camera: Camera, background: torch.Tensor, backend: str = "auto",
                 sh_degree: int | None = None, near: float = DEFAULT_NEAR):
    """Render the model from `camera` through gsgs_engine.render.render()."""
    from gsgs_engine.render import render

    degree = model.active_sh_degree if sh_degree is None else sh_degree
    return render(model.means, model.quats, model.scales, model.opacities, model.sh(degree), camera,
                  sh_degree=degree, background=background, backend=backend, near=near)


def initialise_gaussians(scene, train_views, config: TrainConfig, generator: torch.Generator,
                         log: Callable[[str], None] = print) -> tuple[GaussianModel, InitInfo]:
    """SfM points from the training views only, else the source's points, else random in the bounds."""
    reasons = []
    if config.init in ("auto", "sfm"):
        try:
            from gsgs_engine.sfm import triangulate_known_poses
        except ImportError as exc:
            reasons.append(f"triangulation unavailable ({exc})")
        else:
            try:
                pts, cols = triangulate_known_poses(train_views)
            except GsgsError as exc:
                reasons.append(f"triangulation failed ({exc})")
            else:
                pts = np.asarray(pts, dtype=np.float32).reshape(-1, 3)
                if len(pts) >= config.min_init_points:
                    info = InitInfo("sfm", len(pts), f"{len(pts)} points triangulated from the {len(train_views)} "
                                                     "training views (known poses)")
                    return GaussianModel.from_points(pts, cols, config.sh_degree), info
                reasons.append(f"triangulation gave {len(pts)} points (< {config.min_init_points})")
    if config.init in ("auto", "points"):
        if scene.points is not None and len(scene.points) >= config.min_init_points:
            # the source's points (e.g. a COLMAP model of all photos) may include test-view evidence
            what = "the source's sparse points (may include points seen only by non-training views)"
            info = InitInfo("points", len(scene.points), f"{what}; {'; '.join(reasons)}" if reasons else what)
            return GaussianModel.from_points(scene.points, scene.point_colors, config.sh_degree), info
        n = 0 if scene.points is None else len(scene.points)
        reasons.append(f"the source has {n} sparse points (< {config.min_init_points})")
    if config.init == "mvs":
        raise GsgsError("init 'mvs' (dense multi-view stereo) is made by the orchestration "
                        "(gsgs_engine.reconstruct / gsgs_engine.init.mvs.dense_initial_model) and passed in as initial_model")
    if config.init not in ("auto", "sfm", "points", "random"):
        raise GsgsError(f"unknown init {config.init!r}; use auto, sfm, points, random or mvs")
    lo, hi = scene_bounds_from_cameras([v.camera for v in train_views], scene.near, scene.far)
    model = GaussianModel.random_in_box(lo, hi, config.random_init_points, config.sh_degree, generator=generator)
    why = "; ".join(reasons) if reasons else "requested"
    return model, InitInfo("random", config.random_init_points,
                           f"random in the box {np.round(lo, 3).tolist()}..{np.round(hi, 3).tolist()} ({why})")


def size_extent(camera_extent: float, camera_centers, points) -> float:
    """The scale against which a Gaussian counts as too large (the world-size prune after a reset).

    3DGS uses the camera extent (radius of the camera centres): right for cameras orbiting an
    object, which fits inside their circle. A forward-facing rig's baseline is far smaller than
    the scene it sees (LLFF flower: cameras within 3.5 units, points 22-220 units away), and
    0.1 x the baseline prunes every background Gaussian wider than about 1.4 pixels, which
    densification refills with tens of thousands of tiny ones (measured, flower 3 views at half
    resolution, 1000 steps: 106k Gaussians and 13.6 dB with that prune, 16.9 dB without).
    So: the larger of the camera extent and the median distance from the initial points to
    their nearest training camera. Cloning, splitting and learning rates keep the camera extent.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    centers = np.asarray(camera_centers, dtype=np.float64).reshape(-1, 3)
    finite = np.isfinite(pts).all(axis=1)
    if finite.sum() < 1 or len(centers) == 0:
        return float(camera_extent)
    pts = pts[finite]
    if len(pts) > 20000:  # a median needs no more
        pts = pts[np.linspace(0, len(pts) - 1, 20000).astype(int)]
    nearest = np.linalg.norm(pts[:, None, :] - centers[None, :, :], axis=-1).min(axis=1)
    return float(max(camera_extent, np.median(nearest)))


class Trainer:
    def __init__(self, scene, config: TrainConfig, checkpoint_dir: Path | None = None,
                 cancel_check: Callable[[], bool] | None = None, progress=None,
                 train_views: list | None = None, log: Callable[[str], None] | None = None):
        self.scene = scene
        self.config = config
        self.checkpoint_dir = Path(checkpoint_dir) if checkpoint_dir is not None else None
        self.cancel_check = cancel_check or (lambda: False)
        self.progress = progress
        self.log = log or (lambda msg: None)
        self.train_views = list(scene.train if train_views is None else train_views)
        if not self.train_views:
            raise GsgsError(f"{scene.source}: no training views; check --train-split / --train-ids")
        self.schedule = Schedule.scaled(config.iters)
        # Every training tensor (model, Adam state, targets, statistics) lives on this device.
        self.device, self.device_description = resolve_device(config.backend)
        t0 = time.perf_counter()
        # a kernel's first-use build (gsplat's CUDA JIT, our C++ CPU kernel) belongs to the set-up, not to step 1
        if self.device.type == "cuda":
            from gsgs_engine.render import cuda_backend

            cuda_backend.load_kernels(self.log)
        elif config.backend != "reference":
            from gsgs_engine.render import cpu_backend

            cpu_backend.available()  # builds or loads it once per process; a failure is reported at the first render
        self.background = torch.as_tensor(np.asarray(scene.background, dtype=np.float32)).to(self.device)
        self.techniques: list[Technique] = []
        self.last_step_renders: list = []  # (render, camera) of the last step's supervised renders
        self._technique_states: dict[str, dict] = {}  # restored from a checkpoint, handed over at add_technique
        # forward work inside each technique's loss_terms (its extra renders, warps and losses), part of "render"
        self.technique_seconds: dict[str, float] = {}
        self.phase_seconds: dict[str, float] = {"init": 0.0, "render": 0.0, "backward": 0.0, "optimise": 0.0,
                                                "densify": 0.0, "checkpoint": 0.0, "evaluate": 0.0}
        self.step = 0
        self.nan_steps_skipped = 0
        self._step_absgrad = False  # this step densifies by AbsGS statistic (techniques/absgrad.py)
        self.nan_causes: dict[str, int] = {}
        self.train_seconds = 0.0
        self.last_losses: dict[str, float] = {}
        self.densify_log: list[dict] = []
        self._signal: int | None = None
        self.backend_used: str | None = None
        self.opacity_resets = 0

        self.extent = self._extent()
        self.size_extent = self.extent  # set from the initial points in setup()
        self._targets, self._alphas = self._load_targets()
        self._premultiplied: list[tuple[torch.Tensor, torch.Tensor] | None] = [None] * len(self._targets)
        self._config_as_set_up: TrainConfig | None = None  # see setup()
        self._kernel_start: dict[str, float] | None = None  # the kernel's phase clocks when training started
        self._reduced_targets: dict[tuple, torch.Tensor] = {}  # coarse-to-fine: (view, w, h) -> area-averaged photo
        self.np_rng = np.random.default_rng(config.seed)
        self.torch_gen = torch.Generator().manual_seed(config.seed)
        torch.manual_seed(config.seed)
        self._order: list[int] = []
        self.model: GaussianModel | None = None
        self.optimizer: torch.optim.Optimizer | None = None
        self.stats: DensifyStats | None = None
        self.init_info: InitInfo | None = None
        self.bg_sphere = None  # BackgroundSphere with config.background_sphere (set up in setup())
        self.bg_optimizer: torch.optim.Optimizer | None = None
        self._sphere_state: dict | None = None  # a checkpoint's sphere and its Adam state, until setup() makes it
        self.phase_seconds["init"] += time.perf_counter() - t0

    # -- set-up -------------------------------------------------------------------------
    def _extent(self) -> float:
        centers = np.stack([v.camera.center for v in self.train_views])
        radius = float(np.linalg.norm(centers - centers.mean(0), axis=1).max()) * 1.1
        if radius < 1e-3:  # one camera (or coincident ones): fall back to unit extent
            radius = 1.0
        return radius

    def _load_targets(self):
        targets, alphas = [], []
        for view in self.train_views:
            img = view.image()
            targets.append(torch.from_numpy(np.ascontiguousarray(img, dtype=np.float32)).to(self.device))
            a = view.alpha() if (self.config.random_background and self.scene.has_alpha) else None
            alphas.append(None if a is None else
                          torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32)).to(self.device))
        return targets, alphas

    def setup(self, resume: bool = False, initial_model: GaussianModel | None = None,
              init_info: InitInfo | None = None) -> None:
        """Initialise a new model (or take `initial_model`, described by `init_info`), or continue from the newest
        checkpoint when `resume`."""
        t0 = time.perf_counter()
        path = ckpt.latest_checkpoint(self.checkpoint_dir) if (resume and self.checkpoint_dir) else None
        if path is not None:
            self._load(path)
            self.log(f"resuming from {path} at step {self.step}/{self.config.iters}")
        else:
            if resume:
                self.log(f"no checkpoint in {self.checkpoint_dir}; starting from scratch")
            if initial_model is not None:
                self.model = initial_model
                self.init_info = init_info or InitInfo("given", initial_model.num_gaussians,
                                                       "a model passed by the caller")
            else:
                self.model, self.init_info = initialise_gaussians(self.scene, self.train_views, self.config,
                                                                  self.torch_gen, self.log)
            self.log(f"init: {self.init_info.method}, {self.init_info.num_points} Gaussians ({self.init_info.reason})")
            self.size_extent = size_extent(self.extent, [v.camera.center for v in self.train_views],
                                           self.model.means.detach().cpu().numpy())
            self.model.to(self.device)  # initialised on the CPU (seeded generator); moved before Adam sees it
            self.optimizer = self._make_optimizer()
            self.stats = DensifyStats(self.model.num_gaussians, device=self.device)
        # The settings as the run was asked for, before any technique adjusts them at install or per step (the
        # count control lowers max_gaussians and the gradient threshold): what a checkpoint records and a resume
        # compares, so a run with techniques resumes after a cancel or a crash.
        self._config_as_set_up = TrainConfig.from_dict(self.config.to_dict())
        self._make_background_sphere(self._sphere_state)
        self.phase_seconds["init"] += time.perf_counter() - t0

    def _make_background_sphere(self, state: dict | None = None) -> None:
        """The background sphere of config.background_sphere (from a checkpoint's `state` when resuming), with its
        own Adam; nothing when it is 0."""
        from gsgs_engine.train import background_sphere as bs

        self.bg_sphere, self.bg_optimizer = None, None
        if not self.config.background_sphere:
            return
        validate_config(self.config)  # a width the sphere takes, and not together with a random background
        if state is not None:
            self.bg_sphere = bs.BackgroundSphere.from_state_dict(state["sphere"], self.device)
        else:
            self.bg_sphere = bs.BackgroundSphere.through([v.camera for v in self.train_views],
                                                         self.background.cpu().numpy(), self.config.background_sphere,
                                                         self.device)
        self.bg_optimizer = torch.optim.Adam([self.bg_sphere.logits], lr=bs.LEARNING_RATE, eps=1e-15)
        if state is not None:
            self.bg_optimizer.load_state_dict(state["adam"])
        w, h = self.bg_sphere.size
        self.log(f"background: a {w}x{h} texture on the sphere through the cameras (centre "
                 f"{np.round(self.bg_sphere.centre, 3).tolist()}, radius {self.bg_sphere.radius:.3g})")

    def _position_lr(self, step: int) -> float:
        """The means' learning rate at `step`: 3DGS's log-linear decay x the scene extent x position_lr_scale."""
        cfg = self.config
        scale = 1.0 if cfg.position_lr_scale is None else float(cfg.position_lr_scale)
        return scale * position_lr(step, cfg.iters, cfg.lr.position_init * self.extent,
                                   cfg.lr.position_final * self.extent)

    def _make_optimizer(self) -> torch.optim.Optimizer:
        lr, p = self.config.attribute_rates(), self.model.params
        groups = [
            {"params": [p["means"]], "lr": self._position_lr(0), "name": "means"},
            {"params": [p["sh_dc"]], "lr": lr.sh_dc, "name": "sh_dc"},
            {"params": [p["sh_rest"]], "lr": lr.sh_rest, "name": "sh_rest"},
            {"params": [p["opacity_logits"]], "lr": lr.opacity, "name": "opacity_logits"},
            {"params": [p["log_scales"]], "lr": lr.scaling, "name": "log_scales"},
            {"params": [p["quats"]], "lr": lr.rotation, "name": "quats"},
        ]
        # fused: one pass over each tensor instead of ~10 (6x faster on the CPU at 100k Gaussians)
        return torch.optim.Adam(groups, lr=0.0, eps=1e-15, fused=True)

    # -- techniques ---------------------------------------------------------------------------------
    def config_as_set_up(self) -> TrainConfig:
        """A copy of the settings as the run was asked for, before any technique adjusted them (a partner field
        trained beside this one starts from these, with its own techniques)."""
        if self._config_as_set_up is None:
            raise GsgsError("the settings as set up exist after Trainer.setup()")
        return TrainConfig.from_dict(self._config_as_set_up.to_dict())

    def add_technique(self, technique: Technique) -> Technique:
        """Let `technique` take part in training (see gsgs_engine.train.technique); call after setup()."""
        if self.model is None:
            raise GsgsError("add a technique after Trainer.setup(): it may need the model")
        if any(t.name == technique.name for t in self.techniques):
            raise GsgsError(f"technique {technique.name!r} is already installed")
        self.techniques.append(technique)
        technique.install(self)
        saved = self._technique_states.pop(technique.name, None)
        if saved is not None:
            technique.load_state_dict(saved)
        return technique

    def technique(self, name: str) -> Technique | None:
        return next((t for t in self.techniques if t.name == name), None)

    # -- rendering ------------------------------------------------------------------------------
    def gaussians_for(self, camera: Camera, sh_degree: int | None = None) -> dict:
        """The rasteriser's inputs for `camera` (a 4D trainer evaluates its model at camera.time)."""
        degree = self.model.active_sh_degree if sh_degree is None else sh_degree
        m = self.model
        sh_dc, sh_rest = m.sh_parts()  # render() reads both where they are (technique.joined_sh to rewrite them)
        return {"means": m.means, "quats": m.quats, "scales": m.scales, "opacities": m.opacities,
                "sh": sh_dc, "sh_rest": sh_rest, "sh_degree": degree}

    def render(self, camera: Camera, background: torch.Tensor | None = None, sh_degree: int | None = None):
        """Render the model as it is (evaluation, pseudo-view generation): no technique changes it."""
        from gsgs_engine.render import render

        inputs = self.gaussians_for(camera, sh_degree)
        bg = self.background if background is None else background
        out = render(inputs["means"], inputs["quats"], inputs["scales"], inputs["opacities"], inputs["sh"], camera,
                     sh_degree=inputs["sh_degree"], background=bg,
                     backend=self.config.backend, near=self.config.novel_view_near, sh_rest=inputs.get("sh_rest"))
        return self._behind(out, camera, bg)

    def _behind(self, out, camera: Camera, background: torch.Tensor):
        """A render with the run's background sphere behind it (as rendered: over the constant `background`)."""
        return out if self.bg_sphere is None else self.bg_sphere.composite(out, camera, background)

    def training_inputs(self, ctx: StepContext | None, camera: Camera) -> dict:
        """The rasteriser's inputs of a supervised render of this step: `gaussians_for(camera)` rewritten by the
        techniques' `render_inputs` hooks (none without a step context)."""
        inputs = self.gaussians_for(camera)
        if ctx is not None:
            for t in self.techniques:
                inputs = t.render_inputs(ctx, inputs)
        return inputs

    def render_for_training(self, ctx: StepContext | None, camera: Camera, background: torch.Tensor | None = None,
                            absgrad: bool | None = None):
        """A supervised render of this step: the techniques' `render_inputs` hooks may rewrite its inputs.

        absgrad: compute AbsGS's statistic in its backward (None: when this step densifies by it, i.e. for the
        renders that may feed densification; a technique's render that never does passes False)."""
        from gsgs_engine.render import render

        inputs = self.training_inputs(ctx, camera)
        bg = self.background if background is None else background
        out = render(inputs["means"], inputs["quats"], inputs["scales"], inputs["opacities"], inputs["sh"], camera,
                     sh_degree=inputs["sh_degree"], background=bg,
                     backend=self.config.backend, absgrad=self._step_absgrad if absgrad is None else absgrad,
                     sh_rest=inputs.get("sh_rest"))
        return self._behind(out, camera, bg)

    # -- the loop -------------------------------------------------------------------------------
    def _next_view(self) -> int:
        if not self._order:
            self._order = self.np_rng.permutation(len(self.train_views)).tolist()
        return self._order.pop()

    def _step_background(self) -> torch.Tensor:
        """This step's background: a random colour with `random_background`, else the scene's.

        RGBA views are re-composited on it (`_target`: alpha is learned, and composites in Blender). RGB views keep
        their photo, so a see-through splat shows the random colour and costs loss: no pixel of a photo may stay
        transparent (the effect plan's "opaque" background). With a fixed background the model can make a light
        wall from faint splats over a white background, which a novel view, whose coverage differs, shows as
        holes and haze (docs/inward_rigs.md)."""
        if self.config.random_background:
            return torch.rand(3, generator=self.torch_gen).to(self.device)  # drawn on the CPU: same colours anywhere
        return self.background

    def _target(self, i: int, background: torch.Tensor) -> torch.Tensor:
        alpha = self._alphas[i]
        if alpha is None or background is self.background:
            return self._targets[i]
        # un-composite from the scene background and re-composite on this step's background; the photo's part
        # (premultiplied colour, 1 - alpha) is the same at every step, so it is made once per view (the same
        # operations in the same order: the target is bit-identical to forming it every step)
        if self._premultiplied[i] is None:
            one_minus = 1 - alpha[..., None]
            self._premultiplied[i] = (self._targets[i] - self.background * one_minus, one_minus)
        rgb_premul, one_minus = self._premultiplied[i]
        return rgb_premul + background.to(self.device) * one_minus

    def step_scale(self, step: int) -> float:
        """Render scale of the training view at 1-based `step` (coarse-to-fine; 1.0 when off)."""
        cfg = self.config
        return cfg.coarse_scale if step <= cfg.coarse_fraction * cfg.iters else 1.0

    def _step_view(self, i: int, step: int, target: torch.Tensor) -> tuple[Camera, torch.Tensor]:
        """(camera, target) of training view `i` at this step's resolution; reduced targets are cached."""
        camera = self.train_views[i].camera
        scale = self.step_scale(step)
        if scale == 1.0:
            return camera, target
        from gsgs_engine.train.resample import resize_area

        camera = camera.scaled(scale)
        if target is not self._targets[i]:  # composited on this step's random background: not cached
            return camera, resize_area(target, camera.height, camera.width)
        key = (i, camera.width, camera.height)
        if key not in self._reduced_targets:
            self._reduced_targets[key] = resize_area(target, camera.height, camera.width)
        return camera, self._reduced_targets[key]

    def gathers_densify_statistics(self, step: int) -> bool:
        """Whether `step`'s renders feed the densification statistics (the 4D trainer gathers its own)."""
        return self.config.densify and step <= self.schedule.densify_until

    def densify_gradient(self, out) -> torch.Tensor | None:
        """A render's screen-space statistic after backward: its means2d's gradient, or with the densification
        gradient "abs" (techniques/absgrad.py) the per-pixel absolute sums its backward computed."""
        means2d = getattr(out, "means2d", None)
        if means2d is None:
            return None
        return getattr(means2d, "absgrad", None) if self._step_absgrad else means2d.grad

    def train_step(self) -> bool:
        """One optimisation step; False when it was skipped for a non-finite loss or gradient."""
        model, cfg, sched = self.model, self.config, self.schedule
        step = self.step + 1  # 1-based like 3DGS's iteration counter
        for group in self.optimizer.param_groups:
            if group["name"] == "means":
                group["lr"] = self._position_lr(step)
        if sched.is_sh_raise_step(step):
            model.raise_sh_degree()

        for t in self.techniques:
            t.before_step(self, step)
        densifying = cfg.densify and step <= sched.densify_until
        self._step_absgrad = self.gathers_densify_statistics(step) and cfg.densify_config.gradient == "abs"
        t0 = time.perf_counter()
        i = self._next_view()
        bg = self._step_background()
        camera, target = self._step_view(i, step, self._target(i, bg))
        ctx = StepContext(self, step, i, None, target, bg, camera=camera)
        out = self.render_for_training(ctx, camera, bg)
        ctx.render = out
        ctx.renders.append((out, camera))
        self.backend_used = getattr(out, "backend", self.config.backend)
        terms = photometric_terms(out.color, target, cfg.lambda_dssim)
        for t in self.techniques:
            t_start = time.perf_counter()
            extra = t.loss_terms(ctx) or {}
            self.technique_seconds[t.name] = self.technique_seconds.get(t.name, 0.0) + time.perf_counter() - t_start
            for name, value in extra.items():
                if name in terms:
                    raise GsgsError(f"technique {t.name!r} adds loss term {name!r}, which another term already has")
                terms[name] = value if isinstance(value, tuple) else (1.0, value)
        loss = total_loss(terms)
        self.last_step_renders = ctx.renders
        t1 = time.perf_counter()
        self.phase_seconds["render"] += t1 - t0

        ok = bool(torch.isfinite(loss))
        if ok:
            loss.backward()
            ok = grads_finite(model.params.values())
        t2 = time.perf_counter()
        self.phase_seconds["backward"] += t2 - t1
        if not ok:
            # never let NaN/Inf reach the parameters or Adam's moments
            cause = nonfinite_cause(terms, loss, model.params)
            self.nan_causes[cause] = self.nan_causes.get(cause, 0) + 1
            self.optimizer.zero_grad(set_to_none=True)
            if self.bg_optimizer is not None:
                self.bg_optimizer.zero_grad(set_to_none=True)
            self.nan_steps_skipped += 1
            self.step = step
            self.last_losses = {"loss": float("nan")}
            self.log(f"step {step}: non-finite loss or gradient ({cause}), step skipped "
                     f"({self.nan_steps_skipped} so far)")
            check_skipped(self.nan_steps_skipped, step, self.config.iters, self.nan_causes)
            return False

        if densifying:
            for r, cam in ctx.renders:
                self.stats.accumulate(self.densify_gradient(r), r.radii.detach(), cam.width, cam.height)
        self.optimizer.step()
        self.optimizer.zero_grad(set_to_none=True)
        if self.bg_optimizer is not None:
            self.bg_optimizer.step()
            self.bg_optimizer.zero_grad(set_to_none=True)
        t3 = time.perf_counter()
        self.phase_seconds["optimise"] += t3 - t2

        if densifying:
            if sched.is_densify_step(step):
                info = densify_and_prune(model, self.optimizer, self.stats, self.extent, cfg.densify_config,
                                         prune_large=self.opacity_resets > 0, generator=self.torch_gen,
                                         size_extent=self.size_extent)
                info["step"] = step
                self.densify_log.append(info)
            white = bool(torch.all(self.background == 1.0))
            if sched.is_opacity_reset_step(step):
                reset_opacity(model, self.optimizer)
                # 3DGS prunes by world size only after the first reset; a short run may have none
                self.opacity_resets += 1
            elif white and sched.white_reset_step(step):
                reset_opacity(model, self.optimizer)
        self.phase_seconds["densify"] += time.perf_counter() - t3

        self.last_losses = {"loss": float(loss.detach()), **{k: float(v.detach()) for k, (_, v) in terms.items()}}
        self.step = step
        for t in self.techniques:
            t.after_step(self, step)
        return True

    def _on_signal(self, signum, frame) -> None:
        if self._signal is not None:  # a second signal: stop now
            raise KeyboardInterrupt
        self._signal = signum

    def kernel_seconds(self) -> dict[str, float] | None:
        """Seconds the compiled CPU kernel spent per phase in this process's training loop so far (projection,
        binning, compositing forward / backward, ...), or None when it did not run here."""
        if self._kernel_start is None:
            return None
        now = _kernel_clock()
        return None if now is None else {k: now[k] - self._kernel_start.get(k, 0.0) for k in now}

    def train(self, until: int | None = None) -> None:
        """Train up to step `until` (default: the configured total); see the module docstring."""
        if self._kernel_start is None:
            self._kernel_start = _kernel_clock() or {}  # not loaded yet: its clocks start at zero
        target = self.config.iters if until is None else min(until, self.config.iters)
        handlers = {}
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                handlers[sig] = signal.signal(sig, self._on_signal)
        try:
            while self.step < target:
                if self.cancel_check():
                    path = self.save_checkpoint()
                    raise TrainingCancelled(self.step, path)
                t0 = time.perf_counter()
                self.train_step()
                self.train_seconds += time.perf_counter() - t0
                if self.progress is not None:
                    self.progress.update(self.step, self.last_losses, num_gaussians=self.model.num_gaussians)
                if (self.checkpoint_dir is not None and self.config.checkpoint_every > 0
                        and self.step % self.config.checkpoint_every == 0 and self.step < self.config.iters):
                    self.save_checkpoint()
                if self._signal is not None:
                    path = self.save_checkpoint()
                    raise TrainingInterrupted(self._signal, self.step, path)
        finally:
            for sig, h in handlers.items():
                signal.signal(sig, h)

    # -- checkpoints ------------------------------------------------------------------------------
    def state(self) -> dict:
        config = self._config_as_set_up if self._config_as_set_up is not None else self.config
        return {"format": CHECKPOINT_FORMAT, "step": self.step, "config": config.to_dict(),
                "model": self.model.state_dict(), "optimizer": self.optimizer.state_dict(),
                "densify_stats": self.stats.state_dict(), "init": self.init_info.to_dict(),
                "train_names": [v.name for v in self.train_views],
                "rng": {"numpy": self.np_rng.bit_generator.state, "torch_gen": self.torch_gen.get_state(),
                        "torch": torch.get_rng_state(), "order": list(self._order)},
                "nan_steps_skipped": self.nan_steps_skipped, "train_seconds": self.train_seconds,
                "opacity_resets": self.opacity_resets, "size_extent": self.size_extent,
                "phase_seconds": dict(self.phase_seconds), "densify_log": self.densify_log,
                "techniques": {t.name: t.state_dict() for t in self.techniques},
                **({"background_sphere": {"sphere": self.bg_sphere.state_dict(),
                                          "adam": self.bg_optimizer.state_dict()}} if self.bg_sphere is not None else {}),
                "scene_fingerprint": self.scene_fingerprint()}

    def scene_fingerprint(self) -> dict:
        from gsgs_engine.run_folder import scene_fingerprint

        return scene_fingerprint(self.train_views, self._targets)

    def save_checkpoint(self) -> Path | None:
        if self.checkpoint_dir is None:
            return None
        t0 = time.perf_counter()
        path = ckpt.save_checkpoint(self.checkpoint_dir, self.step, self.state())
        self.phase_seconds["checkpoint"] += time.perf_counter() - t0
        return path

    def _load(self, path: Path) -> None:
        state = ckpt.load_checkpoint(path)
        if state.get("format") != CHECKPOINT_FORMAT:
            raise GsgsError(f"{path}: checkpoint format {state.get('format')!r} is not {CHECKPOINT_FORMAT}; "
                            f"{ckpt.START_AFRESH}")
        names = [v.name for v in self.train_views]
        if state["train_names"] != names:
            raise GsgsError(f"{path}: this checkpoint was trained on views {state['train_names']}, not {names}; "
                            "resume with the same training views or use a new --out folder")
        from gsgs_engine.run_folder import check_resume

        check_resume(path, state, self.scene_fingerprint(), self.config.to_dict())
        saved = TrainConfig.from_dict(state["config"])
        if saved.iters != self.config.iters:
            self.log(f"the checkpoint's schedule has {saved.iters} iterations; keeping it (asked: {self.config.iters})")
        if saved.backend != self.config.backend:
            # where to run is this run's choice (a GPU checkpoint may resume on a CPU machine and vice versa)
            self.log(f"the checkpoint was trained with backend {saved.backend!r}; continuing with "
                     f"{self.config.backend!r} on {self.device_description}")
            saved.backend = self.config.backend
        self.config = saved
        self.schedule = Schedule.scaled(saved.iters)
        # the checkpoint holds CPU tensors (loaded with map_location="cpu"); Adam's state follows its parameters
        self.model = GaussianModel.from_state_dict(state["model"]).to(self.device)
        self.optimizer = self._make_optimizer()
        self.optimizer.load_state_dict(state["optimizer"])
        self.stats = DensifyStats(self.model.num_gaussians, device=self.device)
        self.stats.load_state_dict(state["densify_stats"])
        self.init_info = InitInfo(**state["init"])
        self.step = int(state["step"])
        self.size_extent = float(state.get("size_extent", self.extent))
        self.np_rng.bit_generator.state = state["rng"]["numpy"]
        self.torch_gen.set_state(state["rng"]["torch_gen"])
        torch.set_rng_state(state["rng"]["torch"])
        self._order = list(state["rng"]["order"])
        self.nan_steps_skipped = int(state["nan_steps_skipped"])
        self.opacity_resets = int(state.get("opacity_resets", 0))
        self.train_seconds = float(state["train_seconds"])
        for k, v in state["phase_seconds"].items():
            self.phase_seconds[k] = self.phase_seconds.get(k, 0.0) + float(v) if k == "init" else float(v)
        self.densify_log = list(state.get("densify_log", []))
        self._technique_states = dict(state.get("techniques", {}))
        self._sphere_state = state.get("background_sphere")


def validate_config(cfg: TrainConfig) -> None:
    if cfg.iters < 1:
        raise GsgsError(f"--iters must be at least 1 (got {cfg.iters})")
    if not 0 <= cfg.sh_degree <= 3:
        raise GsgsError(f"--sh-degree must be 0..3 (got {cfg.sh_degree})")
    if cfg.checkpoint_every < 0:
        raise GsgsError(f"--checkpoint-every must be >= 0 (got {cfg.checkpoint_every})")
    if not 0.0 <= cfg.coarse_fraction <= 1.0:
        raise GsgsError(f"coarse_fraction must be in [0, 1] (got {cfg.coarse_fraction})")
    if not 0.0 < cfg.coarse_scale <= 1.0:
        raise GsgsError(f"coarse_scale must be in (0, 1] (got {cfg.coarse_scale})")
    if cfg.mvs_max_side < 16:
        raise GsgsError(f"--mvs-size must be at least 16 pixels (got {cfg.mvs_max_side})")
    if cfg.mvs_flow not in ("off", "dis", "deepflow"):
        raise GsgsError(f"--mvs-flow must be off, dis or deepflow (got {cfg.mvs_flow!r})")
    if cfg.position_lr_scale is not None and not (np.isfinite(cfg.position_lr_scale) and 0 < cfg.position_lr_scale <= 100):
        raise GsgsError(f"--position-lr-scale must be in (0, 100] (got {cfg.position_lr_scale}); 1 is 3DGS's schedule")
    if cfg.attribute_lr_scale is not None and not (np.isfinite(cfg.attribute_lr_scale)
                                                   and 0 < cfg.attribute_lr_scale <= 100):
        raise GsgsError(f"--attribute-lr-scale must be in (0, 100] (got {cfg.attribute_lr_scale}); 1 is 3DGS's rates")
    if not (np.isfinite(cfg.novel_view_near) and cfg.novel_view_near > 0):
        raise GsgsError(f"novel_view_near must be a positive distance (got {cfg.novel_view_near})")
    from gsgs_engine.train.background_sphere import check_width

    check_width(cfg.background_sphere)
    if cfg.background_sphere and cfg.random_background:
        raise GsgsError("background_sphere and random_background are two backgrounds; use one (the sphere learns the "
                        "background, a random one teaches opaque splats)")
    if cfg.backend not in ("auto", "reference", "cpu", "cuda"):
        raise GsgsError(f"unknown backend {cfg.backend!r}; use auto, reference, cpu or cuda")
