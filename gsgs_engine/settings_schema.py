"""One validation layer for training settings, shared by `gsgs train` flags and job.json.

Every value that enters from a user is checked here before anything runs: its type, its
range and finiteness. A bad value is a GsgsError naming the key (job.json) or the flag
(command line), what is accepted, and what was given. Whole numbers given as integral
floats (JSON `1e3`) or digit strings (`"50"`) are accepted and converted; `30.7` is not a
whole number and is refused rather than truncated.

Standard library only: the Blender add-on may import this module.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from gsgs_engine import GsgsError

_INT_TEXT = re.compile(r"^\s*[+-]?\d+\s*$")


def _num(x) -> str:
    return str(int(x)) if float(x).is_integer() else f"{x:g}"


@dataclass(frozen=True)
class Rule:
    kind: str  # int | float | bool | str | choice | background | effects
    lo: float | None = None
    hi: float | None = None
    flag: str | None = None  # the `gsgs train` flag carrying the same value
    choices: tuple = ()
    also: tuple = ()  # literal values accepted besides the kind (e.g. "auto")
    allow_none: bool = False
    lo_open: bool = False  # lo itself is excluded

    def describe(self) -> str:
        extra = "".join(f" or {a!r}" for a in self.also) + (" or null" if self.allow_none else "")
        if self.kind in ("int", "float"):
            what = "a whole number" if self.kind == "int" else "a finite number"
            lo = "" if self.lo is None else (f"> {_num(self.lo)}" if self.lo_open else f">= {_num(self.lo)}")
            hi = "" if self.hi is None else f"<= {_num(self.hi)}"
            rng = " and ".join(s for s in (lo, hi) if s)
            return f"{what}{' ' + rng if rng else ''}{extra}"
        if self.kind == "bool":
            return "true or false"
        if self.kind == "choice":
            return "one of " + ", ".join(map(str, self.choices)) + extra
        if self.kind == "background":
            return "\"white\", \"black\" or [r, g, b] with each value in 0..1"
        return f"text{extra}"


TRAIN = {
    "iters": Rule("int", 1, 1_000_000, flag="--iters"),
    "sh_degree": Rule("int", 0, 3, flag="--sh-degree", also=("auto",), allow_none=True),
    "backend": Rule("choice", choices=("auto", "cpu", "reference", "cuda"), flag="--backend"),
    "seed": Rule("int", 0, 2 ** 32 - 1, flag="--seed"),
    "checkpoint_every": Rule("int", 0, 10_000_000, flag="--checkpoint-every"),
    "lambda_dssim": Rule("float", 0, 1),
    "random_background": Rule("bool"),
    "init": Rule("choice", choices=("auto", "sfm", "points", "random", "mvs"), flag="--init"),
    "random_init_points": Rule("int", 1, 2_000_000, flag="--init-points"),
    "mvs_max_side": Rule("int", 16, 8192, flag="--mvs-size"),
    "mvs_flow": Rule("choice", choices=("off", "dis", "deepflow"), flag="--mvs-flow"),
    "densify": Rule("bool"),
    "coarse_fraction": Rule("float", 0, 1, flag="--coarse-fraction"),
    "coarse_scale": Rule("float", 0, 1, lo_open=True, flag="--coarse-scale"),
    "position_lr_scale": Rule("float", 0, 100, lo_open=True, flag="--position-lr-scale", also=("auto",),
                              allow_none=True),
    "attribute_lr_scale": Rule("float", 0, 100, lo_open=True, flag="--attribute-lr-scale", also=("auto",),
                               allow_none=True),
    "max_gaussians": Rule("int", 1, 100_000_000),
    "prior": Rule("str", allow_none=True, flag="--prior"),
    "resolution_scale": Rule("float", 0, 4, lo_open=True, flag="--resolution-scale"),
    "max_side": Rule("int", 0, 100_000, flag="--max-side"),
    "background": Rule("background"),
    "preset": Rule("str", allow_none=True),
}
PRIOR = {
    "depth_source": Rule("str", flag="--depth-source"),
    "num_pseudo": Rule("int", 0, 1000, flag="--pseudo-views"),
    "rounds": Rule("int", 0, 100, flag="--rounds"),
    "warmup_fraction": Rule("float", 0, 1, flag="--warmup-fraction"),
    "pseudo_weight": Rule("float", 0, 100, flag="--pseudo-weight"),
    "ring_weight": Rule("float", 0, 100, allow_none=True, flag="--ring-weight"),
    "pseudo_every": Rule("int", 1, 1_000_000),
    "pseudo_scale": Rule("float", 0, 1, lo_open=True, flag="--pseudo-scale"),
    "ring_fraction": Rule("float", 0, 1, flag="--ring-fraction"),
    "lambda_reg": Rule("float", 0, 100, flag="--lambda-reg"),
    "depth_reg": Rule("bool"),
    "geo_loss": Rule("bool"),
    "jitter": Rule("float", 0, 10, flag="--pseudo-jitter"),
    "reach": Rule("float", 0, 100, flag="--pseudo-reach"),
    "warp_tolerance": Rule("float", 0, 10, lo_open=True, flag="--warp-tolerance"),
    "diffusion_model": Rule("str", allow_none=True, flag="--diffusion-model"),
    "depth_adapter": Rule("str", allow_none=True, flag="--depth-adapter"),
    "device": Rule("str", flag="--device"),
}
DIFFUSION = {
    "strength": Rule("float", 0, 1, flag="--diffusion-strength"),
    "steps": Rule("int", 1, 1000, flag="--diffusion-steps"),
    "resolution": Rule("int", 64, 4096, flag="--diffusion-resolution"),
    "lora_steps": Rule("int", 0, 100_000, flag="--lora-steps"),
    "guidance": Rule("float", 0, 100),
    "lora_rank": Rule("int", 1, 256),
    "lora_lr": Rule("float", 0, 1),
    "lambda_geo": Rule("float", 0, 100),
}
SFM = {
    "max_image_size": Rule("int", 64, 20000, flag="--max-image-size"),
    "camera_model": Rule("str"),  # the choices are gsgs_engine.sfm.CAMERA_MODELS, checked by run_sfm
    "single_camera": Rule("bool"),
}
DATA = {
    "format": Rule("choice", choices=("auto", "blender", "llff", "colmap", "photos", "job", "n3dv", "panoptic")),
    "train_split": Rule("str", allow_none=True),
    "train_views": Rule("int", 1, 100_000, allow_none=True),
    "resolution_scale": Rule("float", 0, 4, lo_open=True, allow_none=True),
    "background": Rule("background"),
    "frames": Rule("str", allow_none=True),  # frame ids of a scene with time: "0", "0-9", "0,5,9"
}


def _fail(name: str, rule: Rule, value, why: str | None = None) -> GsgsError:
    shown = "null" if value is None else repr(value)
    return GsgsError(f"{name} must be {why or rule.describe()} (got {shown})"
                     + (f"; accepted: {rule.describe()}" if why else ""))


def check_value(name: str, rule: Rule, value):
    """`value` converted to the rule's type, or a GsgsError naming `name` and the accepted range."""
    if value is None:
        if rule.allow_none:
            return None
        raise _fail(name, rule, value)
    if value in rule.also and not isinstance(value, bool):
        return value
    kind = rule.kind
    if kind == "bool":
        if isinstance(value, bool):
            return value
        if isinstance(value, int) and value in (0, 1):
            return bool(value)
        raise _fail(name, rule, value)
    if kind == "str":
        if not isinstance(value, str):
            raise _fail(name, rule, value)
        return value
    if kind == "choice":
        if not isinstance(value, str) or value not in rule.choices:
            raise _fail(name, rule, value)
        return value
    if kind == "background":
        return _check_background(name, rule, value)
    # numbers
    number = _as_number(value, kind)
    if number is None:
        raise _fail(name, rule, value)
    if rule.lo is not None and (number < rule.lo or (rule.lo_open and number == rule.lo)):
        raise _fail(name, rule, value, f"greater than {_num(rule.lo)}" if rule.lo_open else f"at least {_num(rule.lo)}")
    if rule.hi is not None and number > rule.hi:
        raise _fail(name, rule, value, f"at most {_num(rule.hi)}")
    return number


def _as_number(value, kind: str):
    if isinstance(value, bool):
        return None
    if isinstance(value, str):
        text = value.strip()
        if kind == "int":
            return int(text) if _INT_TEXT.match(text) else None
        try:
            value = float(text)
        except ValueError:
            return None
    if isinstance(value, int):
        return value if kind == "int" else float(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            return None
        if kind == "int":
            return int(value) if value.is_integer() else None
        return value
    return None


def _check_background(name: str, rule: Rule, value):
    if isinstance(value, str) and value in ("white", "black"):
        return (1.0, 1.0, 1.0) if value == "white" else (0.0, 0.0, 0.0)
    if isinstance(value, (list, tuple)) and len(value) == 3:
        rgb = [_as_number(v, "float") for v in value]
        if all(c is not None and 0.0 <= c <= 1.0 for c in rgb):
            return tuple(rgb)
    raise _fail(name, rule, value)


def check_section(section, rules: dict, where: str, strict: bool = False) -> dict:
    """A checked copy of a settings object; `strict` refuses keys `rules` does not know."""
    if not isinstance(section, dict):
        raise GsgsError(f"{where} must be an object of NAME: value pairs (got {type(section).__name__} "
                        f"{_short(section)})")
    out = dict(section)
    for key, value in section.items():
        if key in rules:
            out[key] = check_value(f"{where}.{key}", rules[key], value)
        elif strict:
            raise GsgsError(f"{where}: unknown key {key!r}; known: {', '.join(sorted(rules))}")
    return out


def check_settings(settings, where: str = "job.json settings") -> dict:
    """job.json "settings" checked and converted; unknown keys are left to the readers, which name them."""
    if settings is None:
        return {}
    out = check_section(settings, TRAIN, where)
    if out.get("prior_settings") is not None:
        prior = check_section(out["prior_settings"], PRIOR, f"{where}.prior_settings")
        if prior.get("diffusion") is not None:
            prior["diffusion"] = check_section(prior["diffusion"], DIFFUSION, f"{where}.prior_settings.diffusion")
        out["prior_settings"] = prior
    effects = out.get("effects")
    if effects is not None and not isinstance(effects, (str, dict)):
        raise GsgsError(f"{where}.effects must be NAME=VALUE,... text or an object (got {_short(effects)})")
    return out


def check_data(data, where: str = "job.json data") -> dict:
    """job.json "data" checked (shape and types of what the loader reads)."""
    out = check_section(data, DATA, where)
    ids = out.get("train_ids")
    if ids is not None and (not isinstance(ids, list) or not all(isinstance(i, (int, str)) and not isinstance(i, bool)
                                                                  for i in ids)):
        raise GsgsError(f"{where}.train_ids must be a list of view positions or names (got {_short(ids)})")
    for key in ("source", "path"):
        if key in out and not isinstance(out[key], str):
            raise GsgsError(f"{where}.{key} must be a folder path (got {_short(out[key])})")
    return out


def check_args(args) -> None:
    """The same rules for a parsed command line (only the flags the command has)."""
    for rules in (TRAIN, PRIOR, DIFFUSION):
        for rule in rules.values():
            if rule.flag is None:
                continue
            attr = rule.flag[2:].replace("-", "_")
            if hasattr(args, attr) and getattr(args, attr) is not None:
                setattr(args, attr, check_value(rule.flag, rule, getattr(args, attr)))


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."
