"""Mean SSIM and its gradient in one compiled call (csrc/ssim_cpu.cpp), for the training loss on the CPU; with a
mask (pseudo views), the masked mean of the channel-mean SSIM map.

Same value as `metrics.ssim` (3DGS's window, padding and constants; the tests compare the two in
float64 to ~1e-12 and in float32 to ~1e-6) at a fraction of the cost of ~30 torch ops and their
autograd: the 1D window blurs five maps forward, and the gradient needs three more blurs because
the zero-padded symmetric blur is its own adjoint. Differentiable with respect to the rendered
image only; `ssim_mean` returns None where it does not apply (the caller then uses metrics.ssim).
"""

from __future__ import annotations

import functools

import torch

from gsgs_engine.metrics import SSIM_C1, SSIM_C2, SSIM_SIGMA, SSIM_WINDOW, _gaussian_window_1d


@functools.lru_cache(maxsize=1)
def _function():
    class SsimMean(torch.autograd.Function):
        @staticmethod
        def forward(ctx, img, target, window, mask):
            from gsgs_engine.render import cpu_backend

            mean, grad = cpu_backend._ops().ssim_forward_backward(img, target, window, mask, SSIM_C1, SSIM_C2)
            ctx.save_for_backward(grad)
            return mean

        @staticmethod
        @torch.autograd.function.once_differentiable
        def backward(ctx, grad_mean):
            (grad,) = ctx.saved_tensors
            return grad * grad_mean, None, None, None

    return SsimMean


def _usable(img: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None) -> bool:
    if img.device.type != "cpu" or target.device.type != "cpu" or img.dtype not in (torch.float32, torch.float64):
        return False
    if img.dim() != 3 or img.shape != target.shape or target.requires_grad or img.numel() == 0:
        return False
    if mask is not None and (mask.device.type != "cpu" or mask.shape != img.shape[:2] or mask.requires_grad):
        return False
    from gsgs_engine.render import cpu_backend

    return cpu_backend.available()


def ssim_mean(img: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor | None:
    """Mean SSIM of img [H, W, C] against target (no gradient to it), or None when not applicable here. With `mask`
    [H, W] (weights, no gradient) the masked mean of the channel-mean SSIM map, sum m SSIM / max(sum m, 1), as
    losses.dssim_loss forms it with torch."""
    if not _usable(img, target, mask):
        return None
    window = _gaussian_window_1d(SSIM_WINDOW, SSIM_SIGMA, img.dtype, img.device)
    weights = None if mask is None else mask.to(img.dtype).contiguous()
    return _function().apply(img.contiguous(), target.to(img.dtype).contiguous(), window, weights)
