"""Image quality: PSNR and SSIM as 3DGS evaluates them (torch, differentiable), and LPIPS only
when its pretrained weights are on this machine — otherwise None with the reason, never a guess.

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

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_C1 = 0.01**2
SSIM_C2 = 0.03**2

# torchvision checkpoints the `lpips` package's backbones load (torch hub file names)
LPIPS_BACKBONES = {"alex": "alexnet-owt-7be5be79.pth", "vgg": "vgg16-397923af.pth", "squeeze": "squeezenet1_1-b8a52dc0.pth"}
_lpips_models: dict[tuple[str, str], torch.nn.Module] = {}


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


def lpips_or_none(img, gt, weights_dir: str | os.PathLike | None = None, net: str = "alex") -> tuple[float | None, str]:
    """(LPIPS value, description), or (None, why not) when LPIPS cannot be computed here.

    Uses the `lpips` package (its linear layers ship with it) on a torchvision backbone whose
    checkpoint must already be on disk: `weights_dir` or torch's hub directory, in the torch
    hub layout (`<dir>/checkpoints/alexnet-owt-7be5be79.pth` for net="alex"). Nothing is
    downloaded.
    """
    if net not in LPIPS_BACKBONES:
        raise GsgsError(f"metrics: unknown LPIPS network {net!r}; use one of {', '.join(LPIPS_BACKBONES)}")
    try:
        import lpips
    except ImportError:
        return None, ("LPIPS weights not available: the `lpips` package is not installed, and it needs pretrained "
                      f"{net} weights (pip install lpips, then put {LPIPS_BACKBONES[net]} in <torch hub dir>/checkpoints)")
    hub_dirs = ([Path(weights_dir)] if weights_dir is not None else []) + [Path(torch.hub.get_dir())]
    hub_dir = next((d for d in hub_dirs if (d / "checkpoints" / LPIPS_BACKBONES[net]).is_file()), None)
    if hub_dir is None:
        where = " or ".join(str(d / "checkpoints") for d in hub_dirs)
        return None, f"LPIPS weights not available: {LPIPS_BACKBONES[net]} is not in {where}; nothing is downloaded"
    linear = Path(lpips.__file__).parent / "weights" / "v0.1" / f"{net}.pth"
    if not linear.is_file():
        return None, f"LPIPS weights not available: the lpips package has no {linear}; reinstall lpips"
    key = (net, str(hub_dir))
    if key not in _lpips_models:
        previous = torch.hub.get_dir()
        torch.hub.set_dir(str(hub_dir))  # torchvision finds the backbone there instead of downloading it
        try:
            _lpips_models[key] = lpips.LPIPS(net=net, pretrained=True, verbose=False).eval()
        except Exception as exc:  # a corrupt checkpoint or a missing torchvision: report, do not guess
            return None, f"LPIPS unavailable: building the {net} model failed ({type(exc).__name__}: {exc})"
        finally:
            torch.hub.set_dir(previous)
    x, y = _as_bchw(img, gt)
    model = _lpips_models[key].to(x.device)
    if x.shape[1] != 3:
        raise GsgsError(f"metrics: LPIPS needs RGB images, got {x.shape[1]} channels")
    with torch.no_grad():
        value = model(x.float() * 2 - 1, y.float() * 2 - 1)  # LPIPS takes [-1, 1]
    return float(value.mean()), f"LPIPS ({net}, lpips package)"
