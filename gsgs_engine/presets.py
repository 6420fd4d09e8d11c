"""Presets `fast`, `balanced`, `best`: points on the accuracy/time front of `gsgs bench accuracy`.

Each preset is a bench cell (the same keys as gsgs_engine.bench.accuracy_cell), so the full
grid (`gsgs bench accuracy DATA --grid full`) measures exactly what a preset runs.

Chosen from the measured fronts (docs/accuracy_*.md, 2026-11-22):
  - lego_200, 8 views, H100 + gsplat (docs/accuracy_lego_200_h100.md): 300 it 17.79 dB / 11 s,
    1000 it 22.30 / 15 s, 3000 it 24.21 / 42 s are the front; 6000 it is slower and worse
    (23.62 / 91 s: the sparse views overfit), SH 3 and half resolution are off the front.
  - llff_flower, 3 views, H100: 300 it 16.41 / 14 s, 3000 it 16.59 / 46 s, 6000 it 16.87 / 92 s.
  - lego_200, 2-core CPU (docs/accuracy_lego_200.md): 1000 it without a prior 22.84 dB in 130 s;
    with the weights-free prior (warp-inpaint; the SfM depth term switches itself off on lego)
    22.02 dB in 200 s: the prior is off the front. On llff_flower (3 views, CPU) it is on it:
    17.92 dB against 16.33 for 1.6x the time, from filling content beside a forward-facing rig.
    A preset applies to any capture, so none turns the prior on (it would cost lego-like orbits
    0.8 dB); `--prior auto` stays one flag away.
So: fast = 300 iterations, balanced = 1000 (the default schedule), best = 3000; SH from the effect plan.
Issue 14 (docs/sparse_techniques.md, 1000 steps, CPU, one seed) then measured `--prior auto` as it
now runs on sparse static views (dense MVS init, the techniques count_control, dropout, binocular,
opacity_decay, and warp-inpaint pseudo views on forward-facing rigs only): llff_flower 3 views at
half resolution 16.84 -> 20.46 dB (251 s vs 306 s), lego_200 8 views 22.83 -> 25.36 dB (88 s vs 57 s).
So balanced and best use `prior auto` (dense captures get none of it: the plan sees they are not sparse); fast stayed
plain 3DGS until session 24 (below).
The steps of `--prior auto` on the protocols over seeds 0-2 (2-core CPU; docs/speed.md, "Accuracy against steps"):
NeRF-synthetic 26.12 -> 26.99 dB and LLFF 20.65 -> 20.86 from 1000 to 3000 steps, LPIPS 0.02-0.04 better; lego at
10000 steps (seed 0) 25.37 against 25.30 at 3000, for 3.3x the time. So balanced = 1000 and best = 3000 stand, and no
preset trains longer. Since session 14 the 1000-step orbit recipe moves the means at 3x 3DGS's rate (NeRF-synthetic
26.57 dB over seeds 0-2; effect_plan.POSITION_LR_SCALE); 3000 steps, where x3 measured flat, still buy +0.6 dB there.
Since session 45 the orbit recipe below 3000 steps also learns colour, scales and rotations at 3x 3DGS's rates
(effect_plan.ATTRIBUTE_LR_SCALE): NeRF-synthetic seeds 0-2 26.95 -> 27.26 dB at 1000 steps, 23.97 -> 25.26 at 300;
and so does the forward-facing recipe: LLFF 20.69 -> 20.85 dB at 1000 steps, about 1.35x the seconds, 18.92 -> 20.12
at 300. Since session 47 the orbit recipe below 3000 steps adds the depth distortion every 8th step: NeRF-synthetic
27.26 -> 27.40 dB at 1000 steps, 25.26 -> 25.41 at 300, for 1.06x the training seconds.
Session 24 measured fast's 300 steps both ways on the protocols, seeds 0-2, 2-core CPU (docs/speed.md, "Session 24"):
plain 3DGS NeRF-synthetic 19.86 +- 0.17 dB, LLFF 16.13 +- 0.05; `--prior auto` 24.13 +- 0.04 and 18.84 +- 0.03 (SSIM
and LPIPS better too), for about 2x the wait on the orbits and 3.3-4.4x on the forward-facing scenes. Auto's 300 steps
also beat plain 3DGS's 1000 (23.60 / 16.08 dB) in less time, so plain 3DGS is off the front on sparse captures and
fast = 300 steps of the same recipe as balanced. What each preset measured (the add-on's tooltips read these lines;
"a scene" = plan, initialisation, training and prior, not the evaluation; protocol cells, seeds 0-2):
  fast  auto, 300 steps: NeRF-synthetic 8 views 25.41 dB in 23-27 s a scene (session 47: depth distortion; 25.26 with session 45's rates x3 alone), LLFF 3 views 20.12 dB (18.92 before; sessions 45-46, the same VM kind) in 59-85 s (2-core CPU; plain 3DGS, session 24: 19.86 / 16.13 dB in 16-29 s)
  balanced  auto, 1000 steps: NeRF-synthetic 8 views 27.40 dB in 85-104 s a scene (session 47, session 45's VM), LLFF 3 views 20.85 dB in 212-259 s (2-core CPU, session 45's VM)
  best  auto, 3000 steps: NeRF-synthetic 8 views 27.63 dB in 170-212 s a scene (2-core CPU); LLFF 3 views 21.24 dB, 21.20 over seeds 0-5, in 473-547 s of training a scene (2-core CPU)

`apply_preset` fills a `gsgs train` argument namespace (flags the user left at their default
take the preset's value; flags the user typed win) or returns (TrainConfig, PriorConfig,
effect overrides) for scripts.
"""

from __future__ import annotations

from dataclasses import replace

from gsgs_engine import GsgsError

PRESETS: dict[str, dict] = {
    # the recipe of --prior auto, short schedule: the first look (session 24: on sparse captures it beats plain 3DGS's
    # 300 steps by 2.3-4.9 dB a scene (seeds 0-2) for 1.9-4.4x the wait, and plain 3DGS's 1000 steps in less time; SH from the plan)
    "fast": {"iters": 300, "resolution_scale": 1.0, "max_side": 640, "prior": "auto", "pseudo_views": 16, "rounds": 3,
             "sh_degree": "auto", "backend": "auto"},
    # the default schedule: the knee of both measured fronts, with the weights-free sparse-view recipe of
    # --prior auto (the effect plan turns its parts on only where the views are sparse; issue 14)
    "balanced": {"iters": 1000, "resolution_scale": 1.0, "max_side": 640, "prior": "auto", "pseudo_views": 16, "rounds": 3,
                 "sh_degree": "auto", "backend": "auto"},
    # the best measured on lego (3000 beat 6000 there: sparse views overfit longer runs)
    "best": {"iters": 3000, "resolution_scale": 1.0, "max_side": 1600, "prior": "auto", "pseudo_views": 16, "rounds": 3,
             "sh_degree": "auto", "backend": "auto"},
}
PRESET_NAMES = tuple(PRESETS)

# preset key -> `gsgs train` argument dest (as gsgs_engine.commands.train and
# gsgs_engine.priors.config.add_prior_arguments name them)
ARG_DESTS = {"iters": "iters", "resolution_scale": "resolution_scale", "max_side": "max_side", "prior": "prior",
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


def typed_dests(parser, argv: list[str]) -> set[str]:
    """The argument dests whose flag appears in `argv` (`--prior none` or `--prior=none`), so that a typed value
    equal to the parser's default still wins over a preset (`--preset fast --prior none` trains plain 3DGS)."""
    typed = set()
    for action in getattr(parser, "_actions", []):
        for opt in action.option_strings:
            if any(a == opt or a.startswith(opt + "=") for a in argv):
                typed.add(action.dest)
    return typed


def apply_preset(target, parser=None, name: str | None = None):
    """Apply a preset to `gsgs train` arguments or to configs.

    - `apply_preset(args, parser)`: args.preset names the preset (None: nothing happens). Every
      preset key whose argument the user left at the parser's default takes the preset value (a flag
      named in args._argv, the command line `gsgs` parsed, counts as typed even at its default value);
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
    typed = typed_dests(parser, getattr(args, "_argv", None) or [])
    changed = {}
    for key, dest in ARG_DESTS.items():
        if not hasattr(args, dest):
            continue
        value = p[key]
        if key == "sh_degree" and value == "auto":
            continue  # the effect plan decides; a typed --sh-degree still wins
        if dest not in typed and getattr(args, dest) == parser.get_default(dest) and getattr(args, dest) != value:
            setattr(args, dest, value)
            changed[dest] = value
    if getattr(args, "effects", None) in (None, ""):
        args.effects_overrides = effect_overrides(p)
    return changed
