"""render(): one differentiable Gaussian-splat renderer over three backends.

Backends: "cuda" (gsplat, when importable and the inputs live on a CUDA device), "cpu"
(the compiled C++ kernel in cpu_backend.py, once built) and "reference" (pure torch, the
oracle). "auto" picks the first usable one in that order. "cpu" projects and evaluates SH in
the compiled kernel too (project_cpu.py, the same semantics as project.py); "cpu_legacy" is the
earlier split: projection and SH in torch (project.py), only compositing compiled (kept for
side-by-side benchmarks). "reference" uses project.py and the torch compositor.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import torch

from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera
from gsgs_engine.render.project import DEFAULT_NEAR, project_gaussians
from gsgs_engine.render.reference import rasterize_reference
from gsgs_engine.render.sh import num_sh_bases

BACKENDS = ("auto", "reference", "cpu", "cpu_legacy", "cuda")
_warned_cpu_fallback = False


@dataclass
class RenderOutput:
    color: torch.Tensor  # [H, W, 3]
    depth: torch.Tensor  # [H, W], sum d_i alpha_i T_i (eq. 7), not divided by alpha
    alpha: torch.Tensor  # [H, W]
    radii: torch.Tensor  # [N] int32, 0 = culled
    visible: torch.Tensor  # [N] bool
    means2d: torch.Tensor  # [N, 2]; .grad holds the screen-space gradient after backward
    backend: str  # the backend that actually ran


def _cpu_module():
    """(module or None, reason it is unusable or "")."""
    try:
        from gsgs_engine.render import cpu_backend
    except Exception as exc:  # the module is optional: a missing compiler must not break rendering
        return None, f"gsgs_engine.render.cpu_backend could not be imported ({type(exc).__name__}: {exc})"
    try:
        if cpu_backend.available():
            return cpu_backend, ""
        return None, cpu_backend.unavailable_reason()
    except Exception as exc:
        return None, f"the compiled CPU rasteriser failed to load ({type(exc).__name__}: {exc})"


def cpu_status() -> tuple[bool, str]:
    mod, reason = _cpu_module()
    return mod is not None, reason


def cuda_status(device: torch.device | None = None) -> tuple[bool, str]:
    from gsgs_engine.render import cuda_backend
    if not cuda_backend.available():
        return False, cuda_backend.unavailable_reason()
    if device is not None and device.type != "cuda":
        return False, "the Gaussians are on the CPU (move them to a CUDA device to use gsplat)"
    return True, ""


def available_backends() -> dict[str, tuple[bool, str]]:
    """Concrete backend name -> (usable on this machine, reason when not)."""
    cpu = cpu_status()
    return {"reference": (True, ""), "cpu": cpu, "cpu_legacy": cpu, "cuda": cuda_status()}


def _warn_cpu_fallback(reason: str) -> None:
    global _warned_cpu_fallback
    if not _warned_cpu_fallback:
        _warned_cpu_fallback = True
        msg = (f"gsgs: compiled CPU rasteriser unavailable ({reason}); using the much slower pure-torch "
               "reference rasteriser. Run `gsgs build-ext` to build it.")
        warnings.warn(msg, RuntimeWarning, stacklevel=3)


def select_backend(backend: str, device: torch.device, dtype: torch.dtype | None = None) -> str:
    """Resolve "auto" (cuda > cpu > reference) or check that an explicit backend is usable."""
    if backend not in BACKENDS:
        raise GsgsError(f"unknown rasteriser backend {backend!r}; choose one of {', '.join(BACKENDS)}")
    if backend == "reference":
        return backend
    if backend == "cuda":
        ok, reason = cuda_status(device)
        if not ok:
            raise GsgsError(f"rasteriser backend 'cuda' unavailable: {reason}; use backend='auto'")
        if dtype == torch.float64:
            raise GsgsError("rasteriser backend 'cuda' (gsplat) supports float32 only; use backend='reference' for float64")
        return backend
    if backend in ("cpu", "cpu_legacy"):
        if device.type != "cpu":
            raise GsgsError(f"rasteriser backend {backend!r} needs CPU tensors (got {device}); use backend='auto'")
        if dtype == torch.float64:
            raise GsgsError(f"rasteriser backend {backend!r} (compiled kernel) is float32 only; use backend='reference' for float64")
        ok, reason = cpu_status()
        if not ok:
            raise GsgsError(f"rasteriser backend {backend!r} unavailable: {reason}; run `gsgs build-ext` or use backend='reference'")
        return backend
    # auto
    if device.type == "cuda":
        ok, _ = cuda_status(device)
        if ok and dtype != torch.float64:
            return "cuda"
        return "reference"  # the compiled kernel is CPU-only; torch ops run on the GPU
    if dtype == torch.float64:
        return "reference"  # float64 is for gradient checks; the compiled kernel is float32 only
    ok, reason = cpu_status()
    if ok:
        return "cpu"
    _warn_cpu_fallback(reason)
    return "reference"


def rasterize(means2d, conics, colors, opacities, depths, radii, width: int, height: int, background,
              backend: str = "auto", absgrad: bool = False):
    """Composite projected Gaussians -> (color [H, W, 3], depth [H, W], alpha [H, W]).

    absgrad: the backward also sets `means2d.absgrad` (see `render`); the compiled CPU rasteriser only."""
    if backend == "cuda":
        raise GsgsError("rasterize(): the gsplat backend renders whole scenes; call render(..., backend='cuda')")
    chosen = select_backend(backend, means2d.device, means2d.dtype)
    if chosen in ("cpu", "cpu_legacy"):
        from gsgs_engine.render import cpu_backend
        return cpu_backend.rasterize_cpu(means2d, conics, colors, opacities, depths, radii, width, height, background,
                                         absgrad=absgrad)
    if absgrad:
        raise GsgsError(f"absgrad (densifying by AbsGS's absolute gradients) needs the compiled CPU rasteriser or "
                        f"CUDA; this render runs on the {chosen!r} backend ({means2d.dtype}): build the rasteriser "
                        "with `python -m gsgs_engine build-ext`, or leave the densification gradient at 'sum'")
    return rasterize_reference(means2d, conics, colors, opacities, depths, radii, width, height, background)


def _check_inputs(means, quats, scales, opacities, sh, sh_degree: int, camera: Camera, sh_rest=None) -> None:
    n = means.shape[0] if means.dim() == 2 else -1
    problems = []
    if means.dim() != 2 or means.shape[1] != 3:
        problems.append(f"means must be [N, 3] (got {tuple(means.shape)})")
    if tuple(quats.shape) != (n, 4):
        problems.append(f"quats must be [N, 4] (got {tuple(quats.shape)})")
    if tuple(scales.shape) != (n, 3):
        problems.append(f"scales must be [N, 3] (got {tuple(scales.shape)})")
    if tuple(opacities.shape) != (n,):
        problems.append(f"opacities must be [N] (got {tuple(opacities.shape)})")
    if sh_degree not in (0, 1, 2, 3):
        problems.append(f"sh_degree must be 0-3 (got {sh_degree})")
    elif sh_rest is None and (sh.dim() != 3 or sh.shape[0] != n or sh.shape[2] != 3
                              or sh.shape[1] < num_sh_bases(sh_degree)):
        problems.append(f"sh must be [N, K>={num_sh_bases(sh_degree)}, 3] for degree {sh_degree} (got {tuple(sh.shape)})")
    elif sh_rest is not None and (sh.dim() != 3 or sh.shape[0] != n or sh.shape[2] != 3 or sh.shape[1] < 1
                                  or sh_rest.dim() != 3 or sh_rest.shape[0] != n or sh_rest.shape[2] != 3
                                  or sh.shape[1] + sh_rest.shape[1] < num_sh_bases(sh_degree)):
        problems.append(f"sh [N, K0>=1, 3] and sh_rest [N, R, 3] must hold K0 + R >= {num_sh_bases(sh_degree)} "
                        f"coefficients for degree {sh_degree} (got {tuple(sh.shape)} and {tuple(sh_rest.shape)})")
    if camera.width <= 0 or camera.height <= 0:
        problems.append(f"camera image size must be positive (got {camera.width}x{camera.height})")
    if problems:
        raise GsgsError("render(): " + "; ".join(problems))


def render(means: torch.Tensor, quats: torch.Tensor, scales: torch.Tensor, opacities: torch.Tensor,
           sh: torch.Tensor, camera: Camera, sh_degree: int, background, backend: str = "auto",
           near: float = DEFAULT_NEAR, far: float = 1e10, absgrad: bool = False,
           sh_rest: torch.Tensor | None = None) -> RenderOutput:
    """Render Gaussians (means, quats wxyz, linear scales, opacities in [0, 1], SH [N, K, 3]).

    Differentiable w.r.t. every Gaussian input. float16 / bfloat16 inputs are upcast to float32;
    float64 stays float64 (reference backend; the oracle for gradient checks).

    absgrad: after backward, `out.means2d.absgrad` [N, 2] holds each Gaussian's sums over pixels of the pixels'
    own |dL/dmeans2d| per axis, beside `.grad`, their plain sum (AbsGS's densification statistic: gradients of
    opposite sign from different pixels do not cancel). The compiled CPU rasteriser and CUDA only.

    sh_rest: the SH coefficients in two parts, `sh` [N, K0, 3] the first K0 (a model's DC term) and `sh_rest`
    [N, R, 3] the next R, as if `sh` were their concatenation; each part gets its own gradient. The compiled CPU
    projection reads them where they are (no concatenated copy a render, no scattered slice of its gradient);
    the other backends concatenate the coefficients the degree uses.
    """
    if opacities.dim() == 2 and opacities.shape[1] == 1:
        opacities = opacities[:, 0]
    _check_inputs(means, quats, scales, opacities, sh, sh_degree, camera, sh_rest)
    dtype = torch.float64 if means.dtype == torch.float64 else torch.float32
    device = means.device
    means, quats, scales, opacities, sh = (x.to(device=device, dtype=dtype) for x in (means, quats, scales, opacities, sh))
    background = torch.as_tensor(background, device=device).to(dtype).reshape(3)
    chosen = select_backend(backend, device, dtype)
    if sh_rest is not None:
        sh_rest = sh_rest.to(device=device, dtype=dtype)
        if chosen != "cpu":  # one tensor of the degree's coefficients, as GaussianModel.sh() makes it
            sh = torch.cat([sh, sh_rest[:, :max(num_sh_bases(sh_degree) - sh.shape[1], 0)]], dim=1)
            sh_rest = None

    if chosen == "cuda":
        from gsgs_engine.render import cuda_backend
        from gsgs_engine.render.project import view_colors
        center = torch.as_tensor(camera.center, dtype=dtype, device=device)
        colors = view_colors(means, sh, sh_degree, center)
        color, depth, alpha, radii, means2d = cuda_backend.render_gsplat(
            means, quats, scales, opacities, colors, camera, background, near, far, absgrad=absgrad)
        return RenderOutput(color=color, depth=depth, alpha=alpha, radii=radii, visible=radii > 0,
                            means2d=means2d, backend=chosen)

    if chosen == "cpu":
        from gsgs_engine.render.project_cpu import project_gaussians_cpu
        proj = project_gaussians_cpu(means, quats, scales, camera, sh, sh_degree=sh_degree, near=near, far=far,
                                     sh_rest=sh_rest)
    else:
        proj = project_gaussians(means, quats, scales, camera, sh=sh, sh_degree=sh_degree, near=near, far=far)
    means2d = proj.means2d
    if means2d.requires_grad:
        means2d.retain_grad()
    color, depth, alpha = rasterize(means2d, proj.conics, proj.colors, opacities, proj.depths, proj.radii,
                                    camera.width, camera.height, background, backend=chosen, absgrad=absgrad)
    return RenderOutput(color=color, depth=depth, alpha=alpha, radii=proj.radii, visible=proj.visible,
                        means2d=means2d, backend=chosen)
