"""When skipped (non-finite) steps mean a broken run rather than a rare numerical hiccup.

The trainer skips a step whose loss or gradient is NaN / Inf, so one bad pseudo target or a
near-degenerate Gaussian cannot poison Adam. A run that skips more than a small share of
its steps is not training: a NaN setting (--pseudo-weight nan), NaN input points or poses.
It stops with `TrainingDiverged`, naming the cause, instead of exporting a model and ending
`ok`.
"""

from __future__ import annotations

import math

import torch

from gsgs_engine import GsgsError

MAX_SKIPPED_SHARE = 0.05  # of the run's steps
MIN_SKIPPED_ALLOWED = 3  # short runs tolerate a few


class TrainingDiverged(GsgsError):
    """Too many steps had a non-finite loss or gradient."""


def allowed_skips(total_steps: int) -> int:
    return max(MIN_SKIPPED_ALLOWED, int(MAX_SKIPPED_SHARE * total_steps))


def all_finite(t: torch.Tensor) -> bool:
    """`bool(torch.isfinite(t).all())` at the cost of one sum where it holds.

    A NaN or an Inf element makes the sum NaN or Inf, so a finite sum settles it (one vectorised pass: ~0.08 ms for
    the five gradients of 64k Gaussians against ~1 ms for `isfinite(g).all()`). A non-finite sum can also come from
    huge finite elements overflowing: that case is checked element by element.
    """
    return bool(torch.isfinite(t.sum())) or bool(torch.isfinite(t).all())


def grads_finite(params) -> bool:
    """True when every parameter's gradient (None counts as finite) holds no NaN or Inf."""
    return all(p.grad is None or all_finite(p.grad) for p in params)


def nonfinite_cause(terms: dict, loss, params: dict) -> str:
    """Why this step's loss or gradient is not finite, in words: the loss terms (and weights) that
    are NaN / Inf, else the parameters or gradients that are."""
    parts = []
    for name, (weight, value) in terms.items():
        w = float(weight) if not torch.is_tensor(weight) else float(weight.detach())
        v = float(value.detach()) if torch.is_tensor(value) else float(value)
        if not math.isfinite(w):
            parts.append(f"loss term {name} has weight {w}")
        elif not math.isfinite(v):
            parts.append(f"loss term {name} is {v}")
    for name, p in params.items():
        if not bool(torch.isfinite(p.detach()).all()):
            parts.append(f"the model's {name} hold NaN/Inf")
        elif p.grad is not None and not bool(torch.isfinite(p.grad).all()):
            parts.append(f"the gradient of {name} is NaN/Inf")
    if not parts and torch.is_tensor(loss) and not bool(torch.isfinite(loss)):
        parts.append("the total loss is not finite")
    return "; ".join(parts) or "a non-finite value"


def check_skipped(skipped: int, step: int, total_steps: int, causes: dict) -> None:
    """Raise TrainingDiverged once more than allowed_skips(total_steps) steps were skipped."""
    if skipped <= allowed_skips(total_steps):
        return
    top = sorted(causes.items(), key=lambda kv: -kv[1])[:3]
    why = "; ".join(f"{cause} ({n} steps)" for cause, n in top) or "unknown"
    raise TrainingDiverged(
        f"training stopped at step {step}: {skipped} steps had a non-finite loss or gradient (at most "
        f"{allowed_skips(total_steps)} of {total_steps} may). Cause: {why}. Check the settings (weights such as "
        "--pseudo-weight must be finite) and the inputs (points and poses must hold no NaN/Inf)")
