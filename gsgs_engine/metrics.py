"""Image quality: PSNR and SSIM as 3DGS evaluates them (torch, differentiable), and LPIPS v0.1
(VGG or AlexNet) when its converted weights are in the cache — otherwise None with the reason, never a guess.

Images are [H, W, C] or [B, C, H, W], values in [0, 1]; callers clamp renders first, as the
3DGS evaluation does.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from gsgs_engine import GsgsError
from gsgs_engine.lpips import load_lpips, lpips_distance
from gsgs_engine.lpips.networks import MIN_SIDE

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_C1 = 0.01**2
SSIM_C2 = 0.03**2



def _as_bchw(img, gt) -> tuple[torch.Tensor, torch.Tensor]:
    """[H, W, C] -> [1, C, H, W]; [B, C, H, W] as is. numpy arrays are accepted."""
    img = torch.as_tensor(img) if isinstance(img, np.ndarray) else img
    gt = torch.as_tensor(gt) if isinstance(gt, np.ndarray) else gt
    if not (isinstance(img, torch.Tensor) and isinstance(gt, torch.Tensor)):
        raise GsgsError(f"metrics: images must be torch tensors or numpy arrays, got {type(img).__name__} and {type(gt).__name__}")
    if img.shape != gt.shape:
        raise GsgsError(f"metrics: image shape {tuple(img.shape)} differs from ground-truth shape {tuple(gt.shape)}")
    if not img.is_floating_point():
        raise GsgsError(f"metrics: images must be float in [0, 1], got {img.dtype}; divide 8-bit images by 255")
    gt = gt.to(dtype=img.dtype, device=img.device)
    if img.ndim == 3:
        return img.permute(2, 0, 1)[None], gt.permute(2, 0, 1)[None]
    if img.ndim == 4:
        return img, gt
    raise GsgsError(f"metrics: images must be [H, W, C] or [B, C, H, W], got shape {tuple(img.shape)}")


def psnr(img, gt) -> torch.Tensor:
    """Peak signal-to-noise ratio in dB for peak 1, averaged over the batch (inf when equal)."""
    x, y = _as_bchw(img, gt)
    mse = ((x - y) ** 2).flatten(1).mean(dim=1)
    return (-10.0 * torch.log10(mse)).mean()


def masked_psnr(img, gt, mask) -> float | None:
    """PSNR in dB (peak 1) over the pixels where `mask` (H x W, bool) is set; None when it sets none.

    The mean squared error is taken over the masked pixels' channels only, so a small region is
    scored on its own and not diluted by the rest of the image."""
    x, y = _as_bchw(img, gt)
    m = torch.as_tensor(mask, dtype=torch.bool, device=x.device)
    if m.shape != x.shape[-2:]:
        raise ValueError(f"mask is {tuple(m.shape)} but the image is {tuple(x.shape[-2:])}")
    count = int(m.sum())
    if count == 0:
        return None
    mse = ((x - y) ** 2)[..., m].mean()
    return float(-10.0 * torch.log10(mse))


def _gaussian_window_1d(size: int, sigma: float, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    x = torch.arange(size, dtype=torch.float64) - size // 2
    g = torch.exp(-(x**2) / (2.0 * sigma**2))
    return (g / g.sum()).to(dtype=dtype, device=device)


def ssim(img, gt, window_size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> torch.Tensor:
    """Mean structural similarity, as 3DGS's utils/loss_utils.ssim computes it (the mean of `ssim_map`)."""
    return ssim_map(img, gt, window_size, sigma).mean()


def ssim_map(img, gt, window_size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> torch.Tensor:
    """Per-pixel structural similarity (B, C, H, W), as 3DGS's utils/loss_utils.ssim computes it.

    Gaussian window 11 x 11, sigma 1.5, zero padding of window // 2 (so any image size, even
    1 x 1, works and the map has the image's size), C1 = 0.01^2, C2 = 0.03^2. The 2D window
    is separable, so two 1D passes give the same sums at a fraction of the cost; the five
    local moments go through one grouped convolution.
    """
    x, y = _as_bchw(img, gt)
    channels = x.shape[1]
    g = _gaussian_window_1d(window_size, sigma, x.dtype, x.device)
    groups = 5 * channels
    stack = torch.cat([x, y, x * x, y * y, x * y], dim=1)
    pad = window_size // 2
    blurred = F.conv2d(stack, g.view(1, 1, 1, -1).expand(groups, 1, 1, window_size), padding=(0, pad), groups=groups)
    blurred = F.conv2d(blurred, g.view(1, 1, -1, 1).expand(groups, 1, window_size, 1), padding=(pad, 0), groups=groups)
    mu1, mu2, e11, e22, e12 = blurred.split(channels, dim=1)
    mu1_sq, mu2_sq, mu12 = mu1 * mu1, mu2 * mu2, mu1 * mu2
    sigma1_sq, sigma2_sq, sigma12 = e11 - mu1_sq, e22 - mu2_sq, e12 - mu12
    return ((2 * mu12 + SSIM_C1) * (2 * sigma12 + SSIM_C2)) / (
        (mu1_sq + mu2_sq + SSIM_C1) * (sigma1_sq + sigma2_sq + SSIM_C2))


def lpips_or_none(img, gt, net: str = "vgg", cache: str | os.PathLike | None = None) -> tuple[float | None, str]:
    """(mean LPIPS v0.1 over the batch, description), or (None, why not) when the converted weights are absent.

    `net` is "vgg" (what the 3DGS-family papers report) or "alex" (the lpips package's default).
    Weights come from the cache `make` fills (gsgs_engine.lpips.fetch); nothing is downloaded here.
    """
    model, description = load_lpips(net, None if cache is None else Path(cache))
    if model is None:
        return None, description
    x, y = _as_bchw(img, gt)
    if min(x.shape[-2:]) < MIN_SIDE[net]:
        return None, (f"LPIPS ({net}) needs images of at least {MIN_SIDE[net]} x {MIN_SIDE[net]} pixels, "
                      f"got {x.shape[-1]} x {x.shape[-2]}")
    return float(lpips_distance(model, x, y).mean()), description
