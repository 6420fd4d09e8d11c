"""Presets `fast`, `balanced`, `best`: points on the accuracy/time front of `gsgs bench accuracy`.

Each preset is a bench cell (the same keys as gsgs_engine.bench_accuracy_cell), so the full
grid (`gsgs bench accuracy DATA --grid full`) measures exactly what a preset runs.

Measured so far (docs/accuracy_lego_200.md: lego_200, 8 views, the 2-core shared dev machine
under load average ~12, backend auto = compiled CPU rasteriser, commit 548cc05):
  fast      365 s, PSNR 18.26, SSIM 0.743, 1543 Gaussians, 387 MB peak (the plan chose SH 0)
  balanced  not measured yet (the full grid has not run here)
  best      not measured yet
The one prior cell measured (300 iterations, prior auto) scored PSNR 9.88 in 1109 s, far off
the front (its first round fell right after an opacity reset; see docs/accuracy.md), so
balanced and best must be re-checked against the full grid before they are trusted.

`apply_preset` fills a `gsgs train` argument namespace (flags the user left at their default
take the preset's value; flags the user typed win) or returns (TrainConfig, PriorConfig,
effect overrides) for scripts.
"""

from __future__ import annotations

from dataclasses import replace

from gsgs_engine import GsgsError

PRESETS: dict[str, dict] = {
    # plain 3DGS, short schedule: the first look (SH from the plan: its SfM is needed for init anyway)
    "fast": {"iters": 300, "resolution_scale": 1.0, "prior": "none", "pseudo_views": 0, "rounds": 0,
             "sh_degree": "auto", "backend": "auto"},
    # the prior where the scene needs it (effect plan), a moderate schedule
    "balanced": {"iters": 1000, "resolution_scale": 1.0, "prior": "auto", "pseudo_views": 8, "rounds": 2,
                 "sh_degree": "auto", "backend": "auto"},
    # the paper's schedule length with more pseudo views and rounds
    "best": {"iters": 3000, "resolution_scale": 1.0, "prior": "auto", "pseudo_views": 16, "rounds": 3,
             "sh_degree": "auto", "backend": "auto"},
}
PRESET_NAMES = tuple(PRESETS)

# preset key -> `gsgs train` argument dest (as gsgs_engine.train.command and
# gsgs_engine.pipeline.add_prior_arguments name them)
ARG_DESTS = {"iters": "iters", "resolution_scale": "resolution_scale", "prior": "prior",
             "pseudo_views": "pseudo_views", "rounds": "rounds", "backend": "backend", "sh_degree": "sh_degree"}


def preset(name: str) -> dict:
    if name not in PRESETS:
        raise GsgsError(f"--preset {name!r}: choose one of {', '.join(PRESET_NAMES)}")
    return dict(PRESETS[name])


def add_preset_argument(parser) -> None:
    parser.add_argument("--preset", choices=PRESET_NAMES, default=None,
                        help="fast | balanced | best: settings from the measured accuracy/time front "
                             "(docs/accuracy_*.md); flags you type override them")


def effect_overrides(p: dict) -> dict:
    """The effect-plan overrides a preset pins (SH degree when not auto; no pseudo views without a prior)."""
    out: dict = {}
    if p["sh_degree"] != "auto":
        out["sh_degree"] = int(p["sh_degree"])
    if p["prior"] == "none":
        out["pseudo_views"] = "off"
    return out


def apply_preset(target, parser=None, name: str | None = None):
    """Apply a preset to `gsgs train` arguments or to configs.

    - `apply_preset(args, parser)`: args.preset names the preset (None: nothing happens). Every
      preset key whose argument the user left at the parser's default takes the preset value;
      returns {dest: value} of what changed, and sets args.effects_overrides (a dict for
      gsgs_engine.effect_plan) when the command has no --effects value of its own.
    - `apply_preset((train_config, prior_config), name=NAME)`: returns new (TrainConfig,
      PriorConfig, effect overrides, resolution_scale); the inputs are not modified.
    """
    if isinstance(target, tuple):
        if name is None:
            raise GsgsError("apply_preset((train_config, prior_config), name=...) needs a preset name")
        p = preset(name)
        tc, pc = target
        tc = replace(tc, iters=int(p["iters"]), backend=p["backend"],
                     sh_degree=int(p["sh_degree"]) if p["sh_degree"] != "auto" else tc.sh_degree)
        pc = replace(pc, prior=p["prior"], num_pseudo=max(int(p["pseudo_views"]), 1), rounds=int(p["rounds"]))
        return tc, pc, effect_overrides(p), float(p["resolution_scale"])
    args = target
    name = name or getattr(args, "preset", None)
    if name is None:
        return {}
    if parser is None:
        raise GsgsError("apply_preset(args, parser): the parser is needed to tell typed flags from defaults")
    p = preset(name)
    changed = {}
    for key, dest in ARG_DESTS.items():
        if not hasattr(args, dest):
            continue
        value = p[key]
        if key == "sh_degree" and value == "auto":
            continue  # the effect plan decides; a typed --sh-degree still wins
        if getattr(args, dest) == parser.get_default(dest) and getattr(args, dest) != value:
            setattr(args, dest, value)
            changed[dest] = value
    if getattr(args, "effects", None) in (None, ""):
        args.effects_overrides = effect_overrides(p)
    return changed
