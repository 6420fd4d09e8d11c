"""Real spherical harmonics (degree 0-3) with the constants and sign convention of 3DGS."""

from __future__ import annotations

import torch

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435)


def num_sh_bases(degree: int) -> int:
    """Coefficients per colour channel for an SH degree: (degree + 1)^2."""
    if degree not in (0, 1, 2, 3):
        raise ValueError(f"SH degree must be 0, 1, 2 or 3 (got {degree})")
    return (degree + 1) ** 2


def rgb_to_sh0(rgb):
    """Colour in [0, 1] -> DC coefficient whose evaluation (plus 0.5) gives that colour back."""
    return (rgb - 0.5) / SH_C0


def sh0_to_rgb(sh0):
    return sh0 * SH_C0 + 0.5


def eval_sh(degree: int, sh: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    """Evaluate SH coefficients `sh` [N, K, 3] (K >= (degree+1)^2) along unit directions `dirs` [N, 3].

    Returns the raw radiance [N, 3]; the renderer adds 0.5 and clamps at 0, as 3DGS does.
    Only the first (degree + 1)^2 coefficients are read, so a degree-3 model can be rendered
    at a lower active degree during training warm-up.
    """
    needed = num_sh_bases(degree)
    if sh.shape[-2] < needed:
        raise ValueError(f"SH degree {degree} needs {needed} coefficients per channel, got {sh.shape[-2]}")
    result = SH_C0 * sh[:, 0]
    if degree == 0:
        return result
    x, y, z = (dirs[:, i:i + 1] for i in range(3))
    result = result - SH_C1 * y * sh[:, 1] + SH_C1 * z * sh[:, 2] - SH_C1 * x * sh[:, 3]
    if degree == 1:
        return result
    xx, yy, zz = x * x, y * y, z * z
    xy, yz, xz = x * y, y * z, x * z
    result = (result
              + SH_C2[0] * xy * sh[:, 4]
              + SH_C2[1] * yz * sh[:, 5]
              + SH_C2[2] * (2.0 * zz - xx - yy) * sh[:, 6]
              + SH_C2[3] * xz * sh[:, 7]
              + SH_C2[4] * (xx - yy) * sh[:, 8])
    if degree == 2:
        return result
    return (result
            + SH_C3[0] * y * (3.0 * xx - yy) * sh[:, 9]
            + SH_C3[1] * xy * z * sh[:, 10]
            + SH_C3[2] * y * (4.0 * zz - xx - yy) * sh[:, 11]
            + SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy) * sh[:, 12]
            + SH_C3[4] * x * (4.0 * zz - xx - yy) * sh[:, 13]
            + SH_C3[5] * z * (xx - yy) * sh[:, 14]
            + SH_C3[6] * x * (xx - 3.0 * yy) * sh[:, 15])
