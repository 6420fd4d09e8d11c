"""gsplat adapter: the CUDA backend of render(), used only where `import gsplat` works and
torch.cuda.is_available().

Written against gsplat's documented `gsplat.rasterization(...)` API (render_mode "RGB+D",
rasterize_mode "classic", eps2d 0.3, tile size 16), which implements the same 3DGS
semantics as our reference backend. This machine has neither CUDA nor gsplat, so this
module is not exercised by the test suite here; its camera conversion is (a pure function).
Colours are evaluated by our SH code (same view direction and +0.5 clamp) and passed in
as [N, 3], so only projection and compositing run in gsplat; its tile binning and Jacobian
clamp differ from ours at the level of single pixels on tile borders.
"""

from __future__ import annotations

import numpy as np
import torch

from gsgs_engine.cameras import Camera

TILE_SIZE = 16
LOW_PASS_DILATION = 0.3


def unavailable_reason() -> str:
    """Why gsplat cannot run here ("" when it can)."""
    if not torch.cuda.is_available():
        return "torch reports no CUDA device (torch.cuda.is_available() is False)"
    try:
        import gsplat  # noqa: F401
    except Exception as exc:  # ImportError, or a broken CUDA build raising at import
        return f"`import gsplat` failed ({type(exc).__name__}: {exc}); pip install gsplat for the CUDA backend"
    return ""


def available() -> bool:
    return unavailable_reason() == ""


_kernels_loaded = False


def load_kernels(log=print) -> float:
    """Load gsplat's compiled CUDA kernels now (-> seconds taken), so that a training run does it before its clock,
    its progress bar and its first step start.

    gsplat compiles its kernels on first use on a machine (a JIT build with the CUDA toolkit's nvcc: 72-82 s on an
    H100; the first H200 cell of docs/speed.md's session 17 spent 81 s in it) and caches them for later processes. A build that
    fails (no nvcc, a toolkit that does not match torch's CUDA) stops here with the fix, not at the first step.
    Once a process: later calls return 0.0 at once, saying nothing.
    """
    import time

    from gsgs_engine import GsgsError

    global _kernels_loaded
    if _kernels_loaded:  # once a process: a bench builds many trainers
        return 0.0
    t0 = time.perf_counter()
    log("gsplat: loading its CUDA kernels (the first use on a machine compiles them: about 1-2 minutes)")
    try:
        from gsplat.cuda._backend import _C
    except Exception as exc:  # the JIT build raises whatever its compiler run raised
        raise GsgsError(f"gsplat's CUDA kernels could not be built or loaded ({type(exc).__name__}: {exc}). Fix: "
                        "install the CUDA toolkit that matches torch's CUDA version (nvcc on the PATH), or a gsplat "
                        "wheel with prebuilt kernels, or train with --backend cpu") from None
    if _C is None:
        raise GsgsError("gsplat's CUDA kernels are not available (gsplat found no CUDA toolkit to build them with). "
                        "Fix: install the CUDA toolkit that matches torch's CUDA version, or a gsplat wheel with "
                        "prebuilt kernels, or train with --backend cpu")
    seconds = time.perf_counter() - t0
    _kernels_loaded = True
    log(f"gsplat: CUDA kernels ready in {seconds:.1f} s")
    return seconds


def camera_to_gsplat(camera: Camera, device, dtype=torch.float32) -> tuple[torch.Tensor, torch.Tensor]:
    """Our OpenCV camera -> gsplat's (viewmats [1, 4, 4] world-to-camera, Ks [1, 3, 3]).

    gsplat uses the same OpenCV convention and the same pixel-centre convention (top-left
    pixel centre at (0.5, 0.5)), so the matrices carry over unchanged.
    """
    viewmat = torch.as_tensor(np.asarray(camera.world_to_camera), dtype=dtype, device=device)[None]
    K = torch.as_tensor(np.asarray(camera.K), dtype=dtype, device=device)[None]
    return viewmat, K


class _ScreenGradHolder:
    """Copies the gradient of gsplat's [1, N, 2] means2d into our [N, 2] tensor's .grad.

    gsplat's rasteriser consumes its own means2d, so a tensor we derived from it would never
    see a gradient; a hook on gsplat's tensor forwards the gradient instead.
    """

    def __init__(self, target: torch.Tensor, source: torch.Tensor | None = None):
        self.target = target
        self.source = source  # with absgrad: gsplat's tensor, whose .absgrad its backward has set by now

    def __call__(self, grad: torch.Tensor) -> None:
        g = grad[0].detach()
        self.target.grad = g.clone() if self.target.grad is None else self.target.grad + g
        absgrad = getattr(self.source, "absgrad", None) if self.source is not None else None
        if absgrad is not None:
            self.target.absgrad = absgrad[0].detach().clone()


def render_gsplat(means, quats, scales, opacities, colors, camera: Camera, background, near: float, far: float,
                  absgrad: bool = False):
    """-> (color [H, W, 3], depth [H, W], alpha [H, W], radii [N] int32, means2d [N, 2]).

    absgrad: gsplat's own AbsGS statistic, copied to the returned means2d's `.absgrad` after backward."""
    import gsplat

    viewmats, Ks = camera_to_gsplat(camera, means.device, means.dtype)
    render_colors, render_alphas, meta = gsplat.rasterization(
        means=means, quats=quats, scales=scales, opacities=opacities, colors=colors,
        viewmats=viewmats, Ks=Ks, width=camera.width, height=camera.height,
        near_plane=near, far_plane=far, eps2d=LOW_PASS_DILATION, sh_degree=None, packed=False,
        tile_size=TILE_SIZE, backgrounds=background[None], render_mode="RGB+D", rasterize_mode="classic",
        absgrad=bool(absgrad),
    )
    color = render_colors[0, ..., :3]
    depth = render_colors[0, ..., 3]  # "D": accumulated sum z_i alpha_i T_i, not normalised (eq. 7)
    alpha = render_alphas[0, ..., 0]
    radii = meta["radii"][0]
    if radii.dim() == 2:  # gsplat >= 1.5 reports separate x / y radii
        radii = radii.max(dim=-1).values
    gs_means2d = meta["means2d"]
    means2d = gs_means2d[0].detach().clone().requires_grad_(gs_means2d.requires_grad)
    if gs_means2d.requires_grad:
        gs_means2d.register_hook(_ScreenGradHolder(means2d, gs_means2d if absgrad else None))
    return color, depth, alpha, radii.to(torch.int32), means2d
