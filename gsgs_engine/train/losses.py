"""Photometric losses of eq. 11 as named terms; the trainer sums weighted terms.

The prior plugs its own terms (depth regularisation, eq. 10) into the same sum.
"""

from __future__ import annotations

import torch

DEFAULT_LAMBDA_DSSIM = 0.2


def _masked_mean(values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean of `values` (H, W) over `mask` (H, W, weights in [0, 1])."""
    m = mask.to(values.dtype)
    return (values * m).sum() / m.sum().clamp_min(1.0)


def l1_loss(render: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """Mean absolute error; with `mask` (H, W) only over the pixels it keeps."""
    if mask is None:
        return (render - target).abs().mean()
    return _masked_mean((render - target).abs().mean(dim=-1), mask)


def dssim_loss(render: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """D-SSIM = 1 - SSIM (3DGS's convention; images [H, W, 3] in [0, 1]); with `mask` (H, W) the
    SSIM map is averaged over the pixels it keeps."""
    from gsgs_engine.metrics import ssim, ssim_map
    from gsgs_engine.train.fused_ssim import ssim_mean

    fused = ssim_mean(render, target, mask)  # compiled CPU path; None elsewhere
    if fused is not None:
        return 1.0 - fused
    if mask is None:
        return 1.0 - ssim(render, target)
    return 1.0 - _masked_mean(ssim_map(render, target)[0].mean(dim=0), mask)


def photometric_terms(render: torch.Tensor, target: torch.Tensor, lambda_dssim: float = DEFAULT_LAMBDA_DSSIM,
                      weight: float = 1.0, prefix: str = "", mask: torch.Tensor | None = None
                      ) -> dict[str, tuple[float, torch.Tensor]]:
    """One view's part of eq. 11: {name: (weight, term)}.

    eq. 11 writes L1 + lambda * D-SSIM; like 3DGS (and the paper's lambda = 0.2 taken from it)
    we weight it (1 - lambda) * L1 + lambda * D-SSIM, which keeps the loss scale at lambda = 0.
    `weight` scales the whole view (pseudo views may count less than real ones); `mask` (H, W)
    limits both terms to the pixels a pseudo target is confident about.
    """
    return {f"{prefix}l1": (weight * (1.0 - lambda_dssim), l1_loss(render, target, mask)),
            f"{prefix}dssim": (weight * lambda_dssim, dssim_loss(render, target, mask))}


def total_loss(terms: dict[str, tuple[float, torch.Tensor]]) -> torch.Tensor:
    """Sum of weighted named terms (eq. 11 when the prior's terms are present)."""
    total = None
    for weight, value in terms.values():
        contribution = weight * value
        total = contribution if total is None else total + contribution
    if total is None:
        raise ValueError("no loss terms")
    return total
