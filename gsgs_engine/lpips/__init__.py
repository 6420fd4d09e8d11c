"""Real LPIPS v0.1 (AlexNet and VGG16) from weights converted once into the cache.

`make` (or `python -m gsgs_engine.lpips.fetch`) fetches and converts the weights; this module only
reads the safetensors files. `load_lpips(net)` returns None with the reason when they are absent
(an offline install), so callers can record "null, because ..." instead of a number.
"""

from __future__ import annotations

from pathlib import Path

import torch

from gsgs_engine import GsgsError

LPIPS_NETS = ("vgg", "alex")
_models: dict[tuple[str, str], torch.nn.Module] = {}


def load_lpips(net: str, cache: Path | None = None) -> tuple[torch.nn.Module | None, str]:
    """(model, description) or (None, why not). Models are cached per (net, file)."""
    from gsgs_engine.lpips.fetch import weights_file
    from gsgs_engine.lpips.networks import LPIPS

    if net not in LPIPS_NETS:
        raise GsgsError(f"metrics: unknown LPIPS network {net!r}; use one of {', '.join(LPIPS_NETS)}")
    path = weights_file(net, cache)
    key = (net, str(path))
    if key in _models:
        return _models[key], f"LPIPS v0.1 ({net})"
    if not path.is_file():
        return None, (f"LPIPS weights not available: {path} is absent; run `make` or "
                      "`python -m gsgs_engine.lpips.fetch` once with network access (nothing is downloaded here)")
    try:
        from safetensors.torch import load_file
    except ImportError:
        return None, "LPIPS weights not available: the safetensors package is not installed (pip install safetensors)"
    try:
        state = load_file(str(path))
        model = LPIPS(net)
        model.load_state_dict(state, strict=False)
        missing = {k for k in model.state_dict() if k not in state} - {"shift", "scale"}
        if missing:
            raise ValueError(f"missing {sorted(missing)[:4]}")
    except Exception as exc:  # a truncated / foreign file: say so, do not guess a number
        return None, (f"LPIPS unavailable: {path} is not a converted {net} checkpoint ({type(exc).__name__}: {exc}); "
                      "run `python -m gsgs_engine.lpips.fetch --force`")
    _models[key] = model
    return model, f"LPIPS v0.1 ({net})"


def lpips_distance(model: torch.nn.Module, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """LPIPS per image for [B, 3, H, W] images in [0, 1] (scaled to LPIPS's [-1, 1] here)."""
    if x.shape[1] != 3:
        raise GsgsError(f"metrics: LPIPS needs RGB images, got {x.shape[1]} channels")
    model = model.to(x.device)
    with torch.no_grad():
        return model(x.float() * 2 - 1, y.float() * 2 - 1)
