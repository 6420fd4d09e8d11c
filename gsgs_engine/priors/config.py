"""The GS-GS prior's settings and plan: what the user asked for, and which effects can run.

`PriorConfig` holds the prior's options (command line: `add_prior_arguments`, job.json:
`prior_config_from_settings`); `resolve_prior_plan` decides, before training, which
generator, depth source and pseudo views run and why. The loop that runs them is
gsgs_engine.train.techniques.prior_loop (Alg. 1).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path

from gsgs_engine import GsgsError

PRIOR_CHOICES = ("none", "depth", "warp", "diffusion", "auto")


@dataclass
class PriorConfig:
    prior: str = "auto"
    depth_source: str = "auto"  # auto | none | sparse | a local depth-estimation model folder
    num_pseudo: int = 16
    rounds: int = 3
    warmup_fraction: float = 0.3  # share of the iterations before the first round
    # loss weight of a pseudo view relative to a real one (eq. 11). 0.1: LLFF protocol, seed 0, warp-inpaint
    # (docs/sparse_techniques.md): flower 20.83 / 20.86 / 20.87 / 20.61 dB at 0.5 / 0.25 / 0.1 / 0.05, horns 20.05 /
    # 20.18 / 20.36 at 0.5 / 0.25 / 0.1 (1.0: 20.78 and 19.78). The targets are worse than the render inside the
    # rig and far better beside it; a light weight keeps the second without much of the first
    pseudo_weight: float = 0.1
    # loss weight of the ring's pseudo views (forward-facing rigs, see `reach`); None: pseudo_weight
    ring_weight: float | None = None
    lambda_reg: float = 0.1  # weight of L_reg (eq. 10, 11)
    depth_reg: bool = True
    geo_loss: bool = True
    jitter: float = 0.0
    pseudo_every: int = 1  # a pseudo view is rendered and supervised every this many steps
    # pseudo views are rendered (and their targets area-averaged) at this fraction of their size (issue 29).
    # 0.5: 3 seeds x both protocols on CUDA (docs/speed.md): LLFF 20.45 -> 20.42 dB, NeRF-synthetic unchanged
    # (its orbit recipe makes no pseudo views); on the CPU 1.2-1.35x faster LLFF cells (seed 0 screens)
    pseudo_scale: float = 0.5
    # forward-facing rigs: `ring_fraction` of the pseudo views on a ring of reach x the rig's radius (0 = none).
    # 5: LLFF protocol, seed 0 (docs/sparse_techniques.md): flower 20.58 -> 20.83 dB against 3, horns 20.11 -> 20.05
    reach: float = 5.0
    # forward-facing rigs: the share of the pseudo views on that ring (the rest between cameras). 1.0: LLFF protocol
    # (docs/sparse_techniques.md), seed 0 flower 20.87 -> 20.91, horns 20.36 -> 20.46 dB against 0.5; 3 seeds in
    # docs/sparse_bench.md
    ring_fraction: float = 1.0
    # warp-inpaint: a photo colours a pseudo-view pixel when its own rendered depth there agrees within this
    # fraction of the depth (visibility); the other covered pixels are inpainted
    warp_tolerance: float = 0.05
    diffusion_model: str | None = None
    depth_adapter: str | None = None
    diffusion: dict = field(default_factory=dict)  # DiffusionSettings overrides (steps, strength, ...)
    device: str = "auto"
    # weights-free sparse-view techniques by name, e.g. ["dropout", "opacity_decay"]
    # (gsgs_engine.train.techniques.catalogue checks them and adds them to the trainer)
    # None: the effect plan chooses (under --prior auto, the measured weights-free recipe when the views are
    # sparse); a list (possibly empty, e.g. from --techniques none) is used as given
    techniques: list | None = None

    def to_dict(self) -> dict:
        return asdict(self)


def diffusion_configured(cfg: PriorConfig) -> bool:
    return bool(cfg.diffusion_model and cfg.depth_adapter and Path(cfg.diffusion_model).is_dir()
                and Path(cfg.depth_adapter).is_dir())


def resolve_prior_plan(cfg: PriorConfig, num_train_views: int, sparse_points: int | None = None) -> dict:
    """Which effects run, from the request and what is available; every choice says why."""
    if cfg.prior not in PRIOR_CHOICES:
        raise GsgsError(f"--prior {cfg.prior!r}: choose one of {', '.join(PRIOR_CHOICES)}")
    plan: dict = {"requested": cfg.prior}
    if cfg.prior == "none":
        return {**plan, "prior": "none", "generator": None, "depth_source": None, "pseudo_views": 0,
                "reason": "plain 3DGS requested"}
    has_diffusion = diffusion_configured(cfg)
    if cfg.prior == "diffusion" and not has_diffusion:
        raise GsgsError("--prior diffusion needs local model folders: --diffusion-model (Stable Diffusion 1.5 "
                        "layout) and --depth-adapter (a depth T2I-Adapter); or use --prior warp / auto")
    generator = {"depth": None, "warp": "warp-inpaint", "diffusion": "diffusion"}.get(cfg.prior)
    if cfg.prior == "auto":
        generator = "diffusion" if has_diffusion else "warp-inpaint"
        plan["generator_reason"] = ("diffusion weights configured" if has_diffusion
                                    else "no diffusion weights configured: the weights-free warp-inpaint generator")
    # depth source: a model folder beats SfM points; none disables the regulariser
    src = cfg.depth_source
    if not cfg.depth_reg:
        depth_source, why = None, "--no-depth-reg"
    elif src not in ("auto", "none", "sparse"):
        if not Path(src).is_dir():
            raise GsgsError(f"--depth-source {src!r}: folder not found; give a local depth-estimation model folder, "
                            "'sparse', 'none' or 'auto'")
        depth_source, why = src, "depth-estimation model folder"
    elif src == "none":
        depth_source, why = None, "--depth-source none"
    elif sparse_points is not None and sparse_points < 50:
        depth_source, why = None, f"no depth model configured and only {sparse_points} SfM points"
        if cfg.prior == "depth":
            raise GsgsError("--prior depth needs a depth source: --depth-source MODEL_DIR, or enough SfM points")
    else:
        depth_source, why = "sparse", "no depth model configured: SfM points of the training views, image-guided"
    if cfg.prior == "depth" and depth_source is None:
        raise GsgsError("--prior depth needs a depth source (--depth-source sparse or a model folder)")
    pseudo = 0 if generator is None else cfg.num_pseudo
    return {**plan, "prior": cfg.prior if cfg.prior != "auto" else f"auto:{generator}", "generator": generator,
            "depth_source": depth_source, "depth_source_reason": why, "pseudo_views": pseudo,
            "rounds": cfg.rounds if generator else 0, "warmup_fraction": cfg.warmup_fraction,
            "pseudo_weight": cfg.pseudo_weight,
            "ring_weight": cfg.pseudo_weight if cfg.ring_weight is None else cfg.ring_weight,
            "lambda_reg": cfg.lambda_reg if depth_source else 0.0,
            "geo_loss": bool(cfg.geo_loss and generator == "diffusion"), "jitter": cfg.jitter,
            "reach": cfg.reach, "ring_fraction": cfg.ring_fraction, "warp_tolerance": cfg.warp_tolerance,
            "pseudo_every": cfg.pseudo_every, "pseudo_scale": cfg.pseudo_scale,
            "depth_convention": "inverse depth (rendered 1/z vs estimated relative inverse depth)"}


def add_prior_arguments(parser) -> None:
    """The prior's options of `gsgs train` (the switches reproduce the paper's ablation rows)."""
    g = parser.add_argument_group("generative prior (GS-GS)")
    g.add_argument("--pseudo-views", type=int, default=PriorConfig.num_pseudo, help="number of pseudo views")
    g.add_argument("--rounds", type=int, default=PriorConfig.rounds, help="rounds of render -> adapt -> generate")
    g.add_argument("--warmup-fraction", type=float, default=PriorConfig.warmup_fraction,
                   help="share of the iterations trained on the real views before the first round")
    g.add_argument("--pseudo-weight", type=float, default=PriorConfig.pseudo_weight,
                   help="loss weight of a pseudo view relative to a real one")
    g.add_argument("--ring-weight", type=float, default=PriorConfig.ring_weight,
                   help="loss weight of the pseudo views on the ring past a forward-facing rig's edges "
                        "(default: --pseudo-weight)")
    g.add_argument("--lambda-reg", type=float, default=PriorConfig.lambda_reg, help="weight of the depth term (eq. 10)")
    g.add_argument("--depth-source", default="auto",
                   help="auto | none | sparse | a local depth-estimation model folder (DPT layout)")
    g.add_argument("--no-depth-reg", action="store_true", help="disable the depth regulariser (ablation)")
    g.add_argument("--no-geo-loss", action="store_true", help="disable the geometry-aware LoRA loss (ablation)")
    g.add_argument("--pseudo-jitter", type=float, default=0.0, help="relative jitter of the pseudo poses")
    g.add_argument("--pseudo-reach", type=float, default=PriorConfig.reach,
                   help="forward-facing rigs: --ring-fraction of the pseudo views on a ring of this many rig radii "
                        "around the cameras, past the rig's edges (0 = all between neighbouring cameras)")
    g.add_argument("--ring-fraction", type=float, default=PriorConfig.ring_fraction,
                   help="forward-facing rigs: the share of the pseudo views on the ring (the rest between cameras)")
    g.add_argument("--pseudo-scale", type=float, default=PriorConfig.pseudo_scale,
                   help="render the pseudo views at this fraction of their size (their targets area-averaged to it)")
    g.add_argument("--warp-tolerance", type=float, default=PriorConfig.warp_tolerance,
                   help="warp-inpaint: relative depth agreement for a training photo to colour a pseudo-view pixel")
    g.add_argument("--diffusion-model", default=None, help="local Stable Diffusion 1.5 folder (diffusers layout)")
    g.add_argument("--depth-adapter", default=None, help="local depth T2I-Adapter folder")
    g.add_argument("--diffusion-strength", type=float, default=0.6,
                   help="1.0 = generate from noise; < 1 = start from the partially noised render")
    g.add_argument("--diffusion-steps", type=int, default=20)
    g.add_argument("--diffusion-resolution", type=int, default=512)
    g.add_argument("--lora-steps", type=int, default=50)
    g.add_argument("--device", default="auto", help="device of the diffusion prior: auto | cpu | cuda")
    parser.add_argument("--techniques", default=None,
                        help="weights-free sparse-view techniques, comma-separated: absgrad, clone_split, "
                             "count_control, unpool, smoothing, dropout, binocular, distortion, opacity_decay, "
                             "coregularisation, exposure "
                             "(options as NAME:KEY=VALUE), or none; "
                             "default: chosen by the effect plan (--prior auto on sparse views: the measured "
                             "recipe); see gsgs_engine.train.techniques.catalogue")


def prior_config_from_args(args) -> PriorConfig:
    return PriorConfig(prior=args.prior, depth_source=args.depth_source, num_pseudo=args.pseudo_views,
                       rounds=args.rounds, warmup_fraction=args.warmup_fraction, pseudo_weight=args.pseudo_weight,
                       ring_weight=args.ring_weight,
                       lambda_reg=args.lambda_reg, depth_reg=not args.no_depth_reg, geo_loss=not args.no_geo_loss,
                       jitter=args.pseudo_jitter, reach=args.pseudo_reach, ring_fraction=args.ring_fraction,
                       warp_tolerance=args.warp_tolerance, pseudo_scale=args.pseudo_scale,
                       diffusion_model=args.diffusion_model,
                       depth_adapter=args.depth_adapter, device=args.device,
                       techniques=techniques_list(getattr(args, "techniques", None), "--techniques"),
                       diffusion={"strength": args.diffusion_strength, "steps": args.diffusion_steps,
                                  "resolution": args.diffusion_resolution, "lora_steps": args.lora_steps})


def prior_config_from_settings(settings: dict) -> PriorConfig:
    """job.json settings -> PriorConfig (keys named as PriorConfig's fields; unknown keys refused).

    A "preset" fills the keys the job leaves out (gsgs_engine.job.settings_with_preset)."""
    from gsgs_engine.job import settings_with_preset

    settings = settings_with_preset(settings)
    known = set(PriorConfig.__dataclass_fields__)
    d = {k: v for k, v in (settings.get("prior_settings") or {}).items()}
    unknown = sorted(set(d) - known)
    if unknown:
        raise GsgsError(f"job.json: unknown prior settings {unknown}; known: {sorted(known)}")
    techniques = techniques_list(settings.get("techniques"), "job.json: settings.techniques")
    return PriorConfig(prior=settings.get("prior", "none") or "none", techniques=techniques, **d)


def techniques_list(value, where: str) -> list | None:
    """None (not given: the effect plan chooses) or the named techniques ("none" / [] : none at all)."""
    if value is None:
        return None
    if isinstance(value, str):
        return [t.strip() for t in value.split(",") if t.strip() and t.strip() != "none"]
    if isinstance(value, list) and all(isinstance(t, str) for t in value):
        return [t.strip() for t in value if t.strip() and t.strip() != "none"]
    raise GsgsError(f"{where} must be a list of technique names or comma-separated text (got {value!r})")
