"""The binocular term's warp and masked L1 in one compiled call (csrc/binocular_cpu.cpp), for training on the CPU.

Same value as `techniques.binocular.warp_shifted_to_view` followed by `masked_l1` (grid_sample's bilinear sampling
with border padding, the same mask; tested against it to float rounding, value and gradients) without grid_sample's
backward and the dozen image-sized torch ops around it. Differentiable with respect to the shifted render and the
training view's z-depth; `binocular_l1` returns None where it does not apply (the caller then uses the torch form).
"""

from __future__ import annotations

import functools

import numpy as np
import torch

from gsgs_engine.cameras import Camera


@functools.lru_cache(maxsize=1)
def _function():
    class BinocularL1(torch.autograd.Function):
        @staticmethod
        def forward(ctx, image, z, target, alpha, coefficients, min_alpha):
            from gsgs_engine.render import cpu_backend

            loss, grad_image, grad_z, mask = cpu_backend._ops().binocular_l1(image, z, target, alpha, *coefficients,
                                                                              min_alpha)
            ctx.save_for_backward(grad_image, grad_z)
            ctx.mark_non_differentiable(mask)
            return loss, mask

        @staticmethod
        @torch.autograd.function.once_differentiable
        def backward(ctx, grad_loss, _grad_mask):
            grad_image, grad_z = ctx.saved_tensors
            return grad_image * grad_loss, grad_z * grad_loss, None, None, None, None

    return BinocularL1


def x_shift(camera: Camera, shifted: Camera) -> float | None:
    """The baseline b when `shifted` is `camera` moved along its own x axis (same rotation), else None."""
    dt = np.asarray(camera.t, dtype=np.float64) - np.asarray(shifted.t, dtype=np.float64)
    if not (np.array_equal(np.asarray(camera.R), np.asarray(shifted.R)) and dt[1] == 0.0 and dt[2] == 0.0):
        return None
    return float(dt[0])


def _usable(z: torch.Tensor, image: torch.Tensor, target: torch.Tensor, alpha: torch.Tensor) -> bool:
    tensors = (z, image, target, alpha)
    if any(t.device.type != "cpu" or t.dtype != torch.float32 for t in tensors) or target.requires_grad:
        return False
    if z.dim() != 2 or alpha.shape != z.shape or target.shape[:2] != z.shape or image.dim() != 3 \
            or image.shape[2] != target.shape[2] or image.numel() == 0 or z.numel() == 0:
        return False
    from gsgs_engine.render import cpu_backend

    return cpu_backend.available()


def binocular_l1(camera: Camera, z: torch.Tensor, shifted: Camera, shifted_image: torch.Tensor, target: torch.Tensor,
                 alpha: torch.Tensor, min_alpha: float) -> tuple[torch.Tensor, torch.Tensor] | None:
    """(mean over all pixels and channels of |warped - target| where the mask holds, the mask (H, W) bool): the
    shifted view's image warped into `camera` with z-depth `z` (H, W), the mask where the warp sees the pixel and
    `alpha` (no gradient) exceeds `min_alpha`. None when the compiled form does not apply (not a pure x shift, not
    float32 CPU tensors, no compiled extension)."""
    baseline = x_shift(camera, shifted)
    if baseline is None or not _usable(z, shifted_image, target, alpha):
        return None
    coefficients = tuple(float(v) for v in (camera.fx, camera.cx, camera.fy, camera.cy, shifted.fx, shifted.cx,
                                            shifted.fy, shifted.cy, baseline))
    return _function().apply(shifted_image.contiguous(), z.contiguous(), target.detach().contiguous(),
                             alpha.detach().contiguous(), coefficients, float(min_alpha))
