"""Projection of 3D Gaussians to screen-space 2D Gaussians (EWA splatting, as in 3DGS).

Pure torch and differentiable; every rasteriser backend consumes its output, so the
culling, clamping and dilation rules below are the single definition for all of them.
Culled Gaussians get radius 0 and safe placeholder values, so no NaN or Inf ever reaches
the backward pass through them.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from gsgs_engine.cameras import Camera
from gsgs_engine.render.sh import eval_sh

LOW_PASS_DILATION = 0.3  # pixels^2 added to the 2D covariance (3DGS anti-aliasing filter)
FRUSTUM_SLACK = 1.3  # tx/tz, ty/tz clamped to 1.3x the image half-extent, as 3DGS
QUAT_EPS = 1e-12
MAX_RADIUS = 2 ** 30  # int32-safe; far larger than any image
DEFAULT_NEAR = 0.01  # Gaussians nearer the camera than this (view-space z) are not drawn


@dataclass
class Projection:
    means2d: torch.Tensor  # [N, 2] pixel coordinates (top-left pixel centre at (0.5, 0.5))
    conics: torch.Tensor  # [N, 3] (A, B, C) of the inverse 2D covariance
    depths: torch.Tensor  # [N] camera-space z
    radii: torch.Tensor  # [N] int32, 0 = culled
    colors: torch.Tensor  # [N, 3] from SH, +0.5, clamped >= 0
    visible: torch.Tensor  # [N] bool


def quat_to_rotmat(quats: torch.Tensor) -> torch.Tensor:
    """Quaternions (w, x, y, z) of any norm [N, 4] -> rotation matrices [N, 3, 3].

    The norm is guarded (rsqrt of a clamped squared norm) so that a zero quaternion gives the
    identity rotation with zero gradient instead of NaN.
    """
    inv_norm = torch.rsqrt((quats * quats).sum(-1, keepdim=True).clamp_min(QUAT_EPS))
    w, x, y, z = (quats * inv_norm).unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], dim=-1).reshape(quats.shape[:-1] + (3, 3))


def scaled_rotation(quats: torch.Tensor, scales: torch.Tensor) -> torch.Tensor:
    """M = R S [N, 3, 3], the factor of the covariance in eq. 2 (Sigma = M M^T)."""
    return quat_to_rotmat(quats) * scales[..., None, :]  # scale the columns of R


def covariance_3d(quats: torch.Tensor, scales: torch.Tensor) -> torch.Tensor:
    """Sigma = R S S^T R^T (eq. 2) from quaternions [N, 4] and linear scales [N, 3]."""
    M = scaled_rotation(quats, scales)
    return M @ M.transpose(-1, -2)


def ewa_covariance_2d(quats: torch.Tensor, scales: torch.Tensor, p_cam: torch.Tensor, W: torch.Tensor,
                      camera: Camera) -> tuple[torch.Tensor, torch.Tensor]:
    """2D covariance J W Sigma W^T J^T + 0.3 I (Sigma from eq. 2) -> ([N, 2, 2], its determinant [N]).

    J is the Jacobian of the perspective projection at the (frustum-clamped) camera-space
    mean; clamping tx/tz to 1.3x the image extent keeps Gaussians far outside the view from
    exploding into huge ellipses (3DGS does the same; gradients stop at the clamp).
    The determinant is not a*c - b^2, which cancels catastrophically for needle-like
    Gaussians: with U = J W R S the undilated covariance is U U^T, whose determinant is the
    sum of squared 2x2 minors of U (Cauchy-Binet), so det = minors + 0.3 trace + 0.09 > 0.
    """
    x, y, z = p_cam.unbind(-1)
    lim_left = FRUSTUM_SLACK * camera.cx / camera.fx
    lim_right = FRUSTUM_SLACK * (camera.width - camera.cx) / camera.fx
    lim_top = FRUSTUM_SLACK * camera.cy / camera.fy
    lim_bottom = FRUSTUM_SLACK * (camera.height - camera.cy) / camera.fy
    txtz = (x / z).clamp(-lim_left, lim_right)
    tytz = (y / z).clamp(-lim_top, lim_bottom)
    zero = torch.zeros_like(z)
    J = torch.stack([
        camera.fx / z, zero, -camera.fx * txtz / z,
        zero, camera.fy / z, -camera.fy * tytz / z,
    ], dim=-1).reshape(z.shape + (2, 3))
    U = J @ W @ scaled_rotation(quats, scales)  # [N, 2, 3]; J W Sigma W^T J^T = U U^T (eq. 2)
    cov2d = U @ U.transpose(-1, -2)
    minors = (U[:, 0, 0] * U[:, 1, 1] - U[:, 0, 1] * U[:, 1, 0]) ** 2 \
        + (U[:, 0, 0] * U[:, 1, 2] - U[:, 0, 2] * U[:, 1, 0]) ** 2 \
        + (U[:, 0, 1] * U[:, 1, 2] - U[:, 0, 2] * U[:, 1, 1]) ** 2
    det = minors + LOW_PASS_DILATION * (cov2d[:, 0, 0] + cov2d[:, 1, 1]) + LOW_PASS_DILATION ** 2
    dilated = cov2d + LOW_PASS_DILATION * torch.eye(2, dtype=cov2d.dtype, device=cov2d.device)
    return dilated, det


def view_colors(means: torch.Tensor, sh: torch.Tensor, sh_degree: int, camera_center: torch.Tensor) -> torch.Tensor:
    """View-dependent colour: SH along normalise(mean - camera centre), plus 0.5, clamped >= 0."""
    dirs = means - camera_center
    dirs = dirs * torch.rsqrt((dirs * dirs).sum(-1, keepdim=True).clamp_min(1e-24))
    return (eval_sh(sh_degree, sh, dirs) + 0.5).clamp_min(0.0)


def project_gaussians(means: torch.Tensor, quats: torch.Tensor, scales: torch.Tensor, camera: Camera,
                      sh: torch.Tensor | None = None, sh_degree: int = 0, near: float = DEFAULT_NEAR,
                      far: float = 1e10) -> Projection:
    """Project N Gaussians into `camera`. Inputs share one float dtype (float32 or float64)."""
    dtype, device = means.dtype, means.device
    R = torch.as_tensor(camera.R, dtype=dtype, device=device)
    t = torch.as_tensor(camera.t, dtype=dtype, device=device)
    n = means.shape[0]

    p_cam = means @ R.T + t
    z = p_cam[:, 2]
    in_range = (z > near) & (z < far) & torch.isfinite(p_cam).all(-1)
    # Replace culled rows before any division so their backward pass is exactly zero.
    safe_point = torch.tensor([0.0, 0.0, 1.0], dtype=dtype, device=device)
    p_safe = torch.where(in_range[:, None], p_cam, safe_point)
    x, y, z_safe = p_safe.unbind(-1)

    cov2d, det = ewa_covariance_2d(quats, scales, p_safe, R, camera)
    a, b, c = cov2d[:, 0, 0], cov2d[:, 0, 1], cov2d[:, 1, 1]
    ok = in_range & (det > 0) & torch.isfinite(det)
    det_safe = torch.where(ok, det, torch.ones_like(det))
    a_s = torch.where(ok, a, torch.ones_like(a))
    b_s = torch.where(ok, b, torch.zeros_like(b))
    c_s = torch.where(ok, c, torch.ones_like(c))
    conics = torch.stack([c_s / det_safe, -b_s / det_safe, a_s / det_safe], dim=-1)

    means2d = torch.stack([camera.fx * x / z_safe + camera.cx, camera.fy * y / z_safe + camera.cy], dim=-1)

    with torch.no_grad():
        # Radius from the largest eigenvalue (no gradient: radii are integers).
        a64, c64 = a_s.double(), c_s.double()
        mid = 0.5 * (a64 + c64)
        lam_max = mid + torch.sqrt((mid * mid - det_safe.double()).clamp_min(0.0))
        radius = torch.ceil(3.0 * torch.sqrt(lam_max.clamp_min(0.0)))
        m = means2d.detach().double()
        on_screen = ((m[:, 0] + radius > 0) & (m[:, 0] - radius < camera.width)
                     & (m[:, 1] + radius > 0) & (m[:, 1] - radius < camera.height))
        visible = ok & on_screen & torch.isfinite(radius)
        radii = torch.where(visible, radius.clamp(1, MAX_RADIUS), torch.zeros_like(radius)).to(torch.int32)

    if sh is None:
        colors = torch.full((n, 3), 0.5, dtype=dtype, device=device)
    else:
        center = torch.as_tensor(camera.center, dtype=dtype, device=device)
        colors = view_colors(means, sh, sh_degree, center)
    return Projection(means2d=means2d, conics=conics, depths=z_safe, radii=radii, colors=colors, visible=visible)
