"""Differentiable Gaussian-splat rendering: one render() API over reference / cpu / cuda backends."""

from gsgs_engine.render.api import RenderOutput, available_backends, rasterize, render, select_backend
from gsgs_engine.render.project import Projection, covariance_3d, project_gaussians, quat_to_rotmat
from gsgs_engine.render.reference import rasterize_reference
from gsgs_engine.render.sh import eval_sh, num_sh_bases, rgb_to_sh0, sh0_to_rgb

__all__ = [
    "RenderOutput", "Projection", "available_backends", "covariance_3d", "eval_sh", "num_sh_bases",
    "project_gaussians", "quat_to_rotmat", "rasterize", "rasterize_reference", "render", "rgb_to_sh0",
    "select_backend", "sh0_to_rgb",
]
