"""The weights-free sparse-view techniques a run can switch on by name.

One switch for all of them: `gsgs train --techniques dropout,opacity_decay` (a job: the setting
"techniques", a list or the same comma-separated text). An item may set the technique's
options: `count_control:per_pixel=0.05`, `opacity_decay:factor=0.99:start=100`. Names and
options are checked before training; the techniques are added in the catalogue's order (so
dropout's `render_inputs` also applies to the binocular technique's shifted render), whatever
order the request names them in.
"""

from __future__ import annotations

import inspect

from gsgs_engine import GsgsError
from gsgs_engine.train.techniques.absgrad import AbsoluteGradients
from gsgs_engine.train.techniques.binocular import BinocularConsistency
from gsgs_engine.train.techniques.clone_split import CloneSplitBoundary
from gsgs_engine.train.techniques.coregularisation import CoRegularisation
from gsgs_engine.train.techniques.count_control import GaussianBudget
from gsgs_engine.train.techniques.distortion import DepthDistortion
from gsgs_engine.train.techniques.dropout import GaussianDropout
from gsgs_engine.train.techniques.exposure import ExposureCompensation
from gsgs_engine.train.techniques.opacity_decay import OpacityDecay
from gsgs_engine.train.techniques.smoothing import SmoothingFilter
from gsgs_engine.train.techniques.unpool import ProximityUnpooling

#: name -> (class, one line for --help); the order is the order techniques are added in
TECHNIQUES = {
    "absgrad": (AbsoluteGradients, "densify by the pixels' absolute screen-space gradients (AbsGS; threshold=4 x "
                                   "3DGS's, gsplat's 0.0008); the compiled CPU rasteriser or CUDA"),
    "clone_split": (CloneSplitBoundary, "densification clones Gaussians up to boundary=0.005 x the scene extent and "
                                        "splits larger ones (3DGS: 0.01)"),
    "count_control": (GaussianBudget, "Gaussian budget tied to the training pixels (ceiling + threshold floor)"),
    "unpool": (ProximityUnpooling, "proximity-guided unpooling (FSGS): midpoints from Gaussians whose neighbours lie "
                                   "far (ratio=3 x the median gap, as an angle from the nearest camera) to each of "
                                   "their k=3 nearest, every=100 steps until=0.5 of the run, within the budget"),
    "smoothing": (SmoothingFilter, "Mip-Splatting's 3D smoothing filter: no Gaussian finer than its finest training "
                                   "pixel (variance=0.2 pixels^2), baked into the model at the last step"),
    "dropout": (GaussianDropout, "progressive Gaussian dropout, training renders only (DropGaussian; "
                                 "guide=density drops crowded Gaussians near the camera more, after D2GS; "
                                 "guide=anchor drops whole neighbourhoods, after DropAnSH-GS; sh_rate=P drops "
                                 "SH bands from the top, DropAnSH-GS's SH dropout)"),
    "binocular": (BinocularConsistency, "shifted-camera disparity-warp self-consistency (Binocular3DGS)"),
    "distortion": (DepthDistortion, "depth distortion (Mip-NeRF 360, 2DGS): the variance of each training ray's "
                                    "depth under its blend weights, weight=6 x, every=8 steps, from start_fraction=0.2 "
                                    "of the run, rendered at scale=0.5"),
    "opacity_decay": (OpacityDecay, "opacity x0.995 per step, no opacity reset, densify to the end (Binocular3DGS)"),
    "coregularisation": (CoRegularisation, "a second field trained alongside, co-regularised at pseudo views and "
                                           "co-pruned (CoR-GS; about 2x the time; static scenes)"),
    "exposure": (ExposureCompensation, "per-camera colour gain and offset learned beside the scene (photos metered "
                                       "apart, camera rigs); novel views keep the average camera's colours"),
}


def _option_value(text: str):
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return text


def parse_techniques(spec, where: str = "--techniques") -> list[dict]:
    """'a,b:key=value' or ['a', 'b:key=value'] -> [{"name": ..., "options": {...}}] in catalogue order.

    "" / "none" / None -> []. Unknown names, unknown options and repeated names stop here with
    one error naming `where` and what is allowed.
    """
    if spec is None:
        return []
    items = spec.split(",") if isinstance(spec, str) else list(spec)
    parsed: dict[str, dict] = {}
    for raw in items:
        item = str(raw).strip()
        if not item or item == "none":
            continue
        name, *opts = item.split(":")
        name = name.strip()
        if name not in TECHNIQUES:
            raise GsgsError(f"{where}: unknown technique {name!r}; choose from {', '.join(TECHNIQUES)} "
                            "(comma-separated, e.g. dropout,opacity_decay)")
        if name in parsed:
            raise GsgsError(f"{where}: technique {name!r} is named twice")
        allowed = [p for p in inspect.signature(TECHNIQUES[name][0].__init__).parameters if p != "self"]
        options = {}
        for opt in opts:
            key, sep, value = opt.partition("=")
            key = key.strip()
            if not sep or key not in allowed:
                raise GsgsError(f"{where}: {name!r} has no option {opt!r}; its options are "
                                f"{', '.join(allowed) or 'none'} (write {name}:OPTION=VALUE)")
            options[key] = _option_value(value.strip())
        parsed[name] = options
    return [{"name": n, "options": parsed[n]} for n in TECHNIQUES if n in parsed]


def make_techniques(parsed: list[dict]) -> list:
    """The Technique objects of `parse_techniques`' result (constructor checks raise GsgsError).

    Co-regularisation's partner field gets its own instances of the other techniques named with it."""
    made = [TECHNIQUES[item["name"]][0](**item["options"]) for item in parsed]
    others = [item for item in parsed if item["name"] != "coregularisation"]
    for technique in made:
        if isinstance(technique, CoRegularisation):
            technique.partner_techniques = lambda: make_techniques(others)
    return made


def techniques_help() -> str:
    return "; ".join(f"{name}: {text}" for name, (_, text) in TECHNIQUES.items())
