"""Depth regularisation (paper §4.4, eq. 8-10): -MS-SSIM between normalised depth maps.

Monocular estimators (DPT and friends) return relative *inverse* depth (near = large).
Compare like with like: `depth_regulariser` takes the rendered inverse depth
(`inverse_depth(rendered)`) against the estimate, so the term never fights the photometric
loss. All functions are safe on flat maps, tiny images and negative contrast terms.
"""

from __future__ import annotations


import torch
import torch.nn.functional as F

MS_SSIM_WEIGHTS = (0.0448, 0.2856, 0.3001, 0.2363, 0.1333)
WINDOW = 11
SIGMA = 1.5
# Normalised maps have unit deviation: a dynamic range of one deviation sets C1, C2.
C1 = 0.01**2
C2 = 0.03**2
EPS = 1e-6


def normalise_depth(depth: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """(D - mean) / std over the (masked) map (eq. 8-9).

    std is computed as sqrt(var + eps^2): a flat map gives zeros with finite gradients
    instead of 0 / 0.
    """
    d = depth.float() if depth.dtype == torch.float16 else depth
    if mask is None:
        mu = d.mean()
        var = ((d - mu) ** 2).mean()
    else:
        w = mask.to(d.dtype)
        n = w.sum().clamp_min(1.0)
        mu = (d * w).sum() / n
        var = (((d - mu) ** 2) * w).sum() / n
    return (d - mu) / torch.sqrt(var + EPS**2)


def inverse_depth(depth: torch.Tensor, alpha: torch.Tensor | None = None, min_depth: float = 1e-3) -> torch.Tensor:
    """Rendered expected depth (eq. 7) -> inverse depth, comparable with DPT-style estimates.

    Eq. 7 is not divided by alpha; where alpha is given the expected depth of the covered
    part is used (depth / alpha), and empty pixels (alpha ~ 0) get inverse depth 0 (far).
    """
    if alpha is not None:
        covered = alpha > 1e-3
        d = torch.where(covered, depth / alpha.clamp_min(1e-3), torch.full_like(depth, float("inf")))
    else:
        d = depth
    return torch.where(torch.isfinite(d), 1.0 / d.clamp_min(min_depth), torch.zeros_like(depth))


def _gaussian_window(size: int, sigma: float, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    coords = torch.arange(size, dtype=dtype, device=device) - (size - 1) / 2.0
    g = torch.exp(-(coords**2) / (2 * sigma**2))
    return g / g.sum()


def _ssim_terms(x: torch.Tensor, y: torch.Tensor, window: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean luminance and contrast-structure terms for [B, 1, H, W] maps (valid convolution)."""
    size = window.numel()
    wx = window.view(1, 1, 1, size)
    wy = window.view(1, 1, size, 1)

    def blur(z: torch.Tensor) -> torch.Tensor:
        return F.conv2d(F.conv2d(z, wx), wy)

    mu_x, mu_y = blur(x), blur(y)
    sxx = blur(x * x) - mu_x**2
    syy = blur(y * y) - mu_y**2
    sxy = blur(x * y) - mu_x * mu_y
    luminance = (2 * mu_x * mu_y + C1) / (mu_x**2 + mu_y**2 + C1)
    cs = (2 * sxy + C2) / (sxx + syy + C2)
    return luminance.mean(dim=(1, 2, 3)), cs.mean(dim=(1, 2, 3))


def ms_ssim_scales(height: int, width: int, window: int = WINDOW, max_scales: int = len(MS_SSIM_WEIGHTS)) -> tuple[int, int]:
    """(number of scales, window size) the image allows.

    Each scale halves the image; the coarsest must still hold one window. Images smaller
    than the window use a smaller odd window (down to 1 pixel: plain SSIM of means).
    """
    short = min(height, width)
    win = min(window, short if short % 2 == 1 else short - 1)
    win = max(win, 1)
    scales = 1
    while scales < max_scales and short // (2**scales) >= win:
        scales += 1
    return scales, win


def ms_ssim(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Multi-scale SSIM of two maps [H, W] or [B, 1, H, W]; 1 for identical maps.

    Uses as many of the 5 standard scales as the image allows (weights renormalised).
    Contrast terms may be negative on normalised inputs; they are clamped before the
    fractional powers so no NaN reaches the gradient.
    """
    if x.dim() == 2:
        x, y = x[None, None], y[None, None]
    dtype = torch.promote_types(x.dtype, torch.float32)
    x, y = x.to(dtype), y.to(dtype)
    scales, win = ms_ssim_scales(x.shape[-2], x.shape[-1])
    weights = torch.tensor(MS_SSIM_WEIGHTS[:scales], dtype=dtype, device=x.device)
    weights = weights / weights.sum()
    window = _gaussian_window(win, SIGMA if win == WINDOW else max(win / 7.0, 0.5), dtype, x.device)
    factors = []
    for s in range(scales):
        luminance, cs = _ssim_terms(x, y, window)
        if s == scales - 1:
            factors.append((luminance * cs).clamp_min(EPS) ** weights[s])
        else:
            factors.append(cs.clamp_min(EPS) ** weights[s])
            x = F.avg_pool2d(x, 2, ceil_mode=False)
            y = F.avg_pool2d(y, 2, ceil_mode=False)
    return torch.stack(factors, dim=0).prod(dim=0).mean()


def depth_regulariser(rendered_inverse_depth: torch.Tensor, estimated_inverse_depth: torch.Tensor,
                      mask: torch.Tensor | None = None) -> torch.Tensor:
    """L_reg = -MS-SSIM(norm(D_est), norm(D_GS)) (eq. 10), both as inverse depth; -1 is a perfect match."""
    d_gs = normalise_depth(rendered_inverse_depth, mask)
    d_est = normalise_depth(estimated_inverse_depth.detach(), mask)
    if mask is not None:
        m = mask.to(d_gs.dtype)
        d_gs, d_est = d_gs * m, d_est * m
    return -ms_ssim(d_est, d_gs)


