"""Compiled projection + SH colour (csrc/project_cpu.cpp): `project.project_gaussians` in one C++ pass.

Same arguments, outputs and gradients as the pure-torch `project_gaussians` (the oracle, which
the tests compare against in float64 to ~1e-12 and in float32 to ~1e-5), but one loop over the
Gaussians forward and one backward instead of ~100 torch ops and their autograd graph. Runs on
torch's threads; no cross-Gaussian reduction, so the result does not depend on the thread count.
Accepts float32 (training) and float64 (gradient checks). The SH coefficients may come in two parts, the head
(the DC term) and the rest, as the model keeps them: the kernel reads both where they are and returns each part's
gradient, so a render copies no concatenation of them (see `project_gaussians_cpu`).
"""

from __future__ import annotations

import functools

import numpy as np
import torch

from gsgs_engine.cameras import Camera
from gsgs_engine.render import cpu_backend
from gsgs_engine.render.project import DEFAULT_NEAR, Projection


def camera_vector(camera: Camera) -> torch.Tensor:
    """R (row-major), t and the centre of `camera` as the float64 [15] tensor the kernel reads."""
    R = np.asarray(camera.R, dtype=np.float64).reshape(9)
    t = np.asarray(camera.t, dtype=np.float64).reshape(3)
    return torch.from_numpy(np.concatenate([R, t, np.asarray(camera.center, dtype=np.float64).reshape(3)]))


@functools.lru_cache(maxsize=1)
def _function():
    class ProjectCpu(torch.autograd.Function):
        @staticmethod
        def forward(ctx, means, quats, scales, sh, sh_rest, cam, intrinsics, sh_degree):
            fx, fy, cx, cy, width, height, near, far = intrinsics
            ops = cpu_backend._ops()
            means2d, conics, depths, radii, colors = ops.project_forward(
                means, quats, scales, sh, sh_rest, cam, fx, fy, cx, cy, width, height, near, far, sh_degree)
            ctx.args = (cam, intrinsics, sh_degree)
            ctx.save_for_backward(means, quats, scales, sh, sh_rest, radii)
            ctx.mark_non_differentiable(radii)
            return means2d, conics, depths, radii, colors

        @staticmethod
        @torch.autograd.function.once_differentiable
        def backward(ctx, g_means2d, g_conics, g_depths, _g_radii, g_colors):
            means, quats, scales, sh, sh_rest, radii = ctx.saved_tensors
            cam, (fx, fy, cx, cy, width, height, near, far), sh_degree = ctx.args
            n, dtype = means.shape[0], means.dtype

            def dense(g, shape):
                return torch.zeros(shape, dtype=dtype) if g is None else g.to(dtype).contiguous()

            d_means, d_quats, d_scales, d_sh, d_sh_rest = cpu_backend._ops().project_backward(
                means, quats, scales, sh, sh_rest, cam, fx, fy, cx, cy, width, height, near, far, sh_degree, radii,
                dense(g_means2d, (n, 2)), dense(g_conics, (n, 3)), dense(g_depths, (n,)), dense(g_colors, (n, 3)))
            return d_means, d_quats, d_scales, d_sh, None if sh_rest is None else d_sh_rest, None, None, None

    return ProjectCpu


def project_gaussians_cpu(means: torch.Tensor, quats: torch.Tensor, scales: torch.Tensor, camera: Camera,
                          sh: torch.Tensor, sh_degree: int = 0, near: float = DEFAULT_NEAR, far: float = 1e10,
                          sh_rest: torch.Tensor | None = None) -> Projection:
    """`project_gaussians` (with SH colours) in the compiled kernel; CPU float32 or float64 tensors.

    sh_rest: with it, `sh` [N, K0, 3] holds the first K0 coefficients and `sh_rest` [N, R, 3] the next ones, the
    colour and gradients being those of `project_gaussians` with `torch.cat([sh, sh_rest], 1)` (only the degree's
    (sh_degree + 1)^2 coefficients are read; the others get zero gradient)."""
    intrinsics = (float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy), int(camera.width),
                  int(camera.height), float(near), float(far))
    means2d, conics, depths, radii, colors = _function().apply(
        means.contiguous(), quats.contiguous(), scales.contiguous(), sh.contiguous(),
        None if sh_rest is None else sh_rest.contiguous(), camera_vector(camera), intrinsics, int(sh_degree))
    return Projection(means2d=means2d, conics=conics, depths=depths, radii=radii, colors=colors, visible=radii > 0)
