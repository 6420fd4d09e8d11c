"""Spacetime Gaussians: the 4D equations, finite-difference gradients through the rasteriser,
PLY round trip with documented extra fields, and "a static model never carries time"."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera
from gsgs_engine.gaussians import GaussianModel
from gsgs_engine.io.ply import read_gaussian_ply, write_gaussian_ply
from gsgs_engine.render import render
from gsgs_engine.spacetime import (PLY_TEMPORAL_FIELDS, SpacetimeModel, gaussians_at, is_spacetime_ply,
                                   model_from_ply, polynomial_position, render_at, rotation_at, temporal_opacity)


@pytest.fixture(autouse=True)
def _single_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _camera(w=8, h=6, time=None):
    return Camera(R=np.eye(3), t=np.array([0.0, 0.0, 3.0]), fx=10.0, fy=10.0, cx=4.2, cy=2.9, width=w, height=h,
                  time=time)


def _random_model(n=5, seed=0) -> SpacetimeModel:
    g = torch.Generator().manual_seed(seed)
    base = GaussianModel.from_points(torch.randn(n, 3, generator=g).numpy() * 0.3, None, 1)
    m = SpacetimeModel.from_static(base, torch.rand(n, generator=g).numpy(), 0.3)
    with torch.no_grad():
        m.params["motion"].copy_(torch.randn(n, 3, 3, generator=g) * 0.2)
        m.params["omega"].copy_(torch.randn(n, 4, generator=g) * 0.3)
    return m


def test_equations_match_hand_computation():
    means = torch.tensor([[1.0, 2.0, 3.0]])
    motion = torch.tensor([[[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 4.0]]])
    dt = torch.tensor([0.5])
    # mu + b1 dt + b2 dt^2 + b3 dt^3
    assert torch.allclose(polynomial_position(means, motion, dt), torch.tensor([[1.5, 2.5, 3.5]]))
    q = rotation_at(torch.tensor([[1.0, 0.0, 0.0, 0.0]]), torch.tensor([[0.0, 2.0, 0.0, 0.0]]), dt)
    assert torch.allclose(q, torch.tensor([[1.0, 1.0, 0.0, 0.0]]) / math.sqrt(2))
    o = temporal_opacity(torch.tensor([0.0]), torch.tensor([0.25]), torch.tensor([0.5]), 0.75)
    assert torch.allclose(o, torch.tensor([0.5 * math.exp(-1.0)]))


def test_at_time_equals_static_model_at_own_centre():
    m = _random_model()
    t0 = float(m.t_center[0].detach())
    means, quats, scales, opac = m.at_time(t0)
    # Gaussian 0 sits at its stored position / rotation / peak opacity at its own temporal centre
    assert torch.allclose(means[0], m.means[0])
    assert torch.allclose(quats[0], m.quats[0] / m.quats[0].norm())
    assert torch.allclose(opac[0], m.opacities[0])
    # others have moved along their polynomial and faded
    far = (m.t_center - t0).abs().argmax()
    assert not torch.allclose(means[far], m.means[far])
    assert opac[far] < m.opacities[far]


def test_gradients_reach_temporal_params_finite_differences_float64():
    """4D -> 3D -> reference rasteriser, float64 gradcheck w.r.t. every temporal parameter."""
    torch.manual_seed(0)
    cam = _camera()
    means = torch.tensor([[0.05, -0.02, 0.1], [-0.1, 0.08, 0.3], [0.12, 0.1, -0.2]], dtype=torch.float64)
    quats = torch.tensor([[0.9, 0.1, -0.2, 0.3], [0.7, -0.3, 0.2, 0.1], [1.0, 0.2, 0.1, -0.1]], dtype=torch.float64)
    scales = torch.tensor([[1.0, 0.8, 0.9], [0.85, 1.1, 1.0], [0.95, 1.0, 0.8]], dtype=torch.float64)
    logits = torch.tensor([0.6, 0.2, 0.8], dtype=torch.float64)
    sh = torch.tensor([[[0.3, -0.2, 0.1]], [[-0.1, 0.2, 0.3]], [[0.2, 0.1, -0.3]]], dtype=torch.float64)
    bg = torch.tensor([0.3, 0.6, 0.1], dtype=torch.float64)
    t_center = torch.tensor([0.3, 0.5, 0.6], dtype=torch.float64, requires_grad=True)
    t_log_scale = torch.log(torch.tensor([0.6, 0.8, 0.7], dtype=torch.float64)).requires_grad_()
    motion = (0.1 * torch.randn(3, 3, 3, dtype=torch.float64)).requires_grad_()
    omega = (0.2 * torch.randn(3, 4, dtype=torch.float64)).requires_grad_()
    t = 0.45

    def f(t_center, t_log_scale, motion, omega):
        dt = t - t_center
        out = render(polynomial_position(means, motion, dt), rotation_at(quats, omega, dt), scales,
                     temporal_opacity(logits, t_center, torch.exp(t_log_scale), t), sh, cam, 0, bg,
                     backend="reference")
        return out.color, out.depth, out.alpha

    with torch.no_grad():
        _, _, alpha = f(t_center, t_log_scale, motion, omega)
        assert 0.1 < float(alpha.min()) and float(alpha.max()) < 0.95  # away from the clamps
    assert torch.autograd.gradcheck(f, (t_center, t_log_scale, motion, omega), eps=1e-6, atol=1e-6, rtol=1e-4,
                                    fast_mode=True)


def test_model_render_backpropagates_into_every_temporal_param():
    m = _random_model(n=6)
    out = render_at(m, _camera(16, 12, time=0.4), torch.ones(3), backend="reference")
    out.color.sum().backward()
    for name in ("t_center", "t_log_scale", "motion", "omega"):
        g = m.params[name].grad
        assert g is not None and bool(torch.isfinite(g).all()) and float(g.abs().sum()) > 0, name


def test_render_at_needs_a_time_for_4d_and_ignores_it_for_3d():
    m = _random_model()
    with pytest.raises(GsgsError, match="finite time"):
        render_at(m, _camera(), torch.ones(3), backend="reference")
    static = GaussianModel.from_points(np.random.default_rng(0).normal(size=(5, 3)) * 0.3, None, 0)
    a = render_at(static, _camera(time=0.1), torch.ones(3), backend="reference").color
    b = render_at(static, _camera(time=0.9), torch.ones(3), backend="reference").color
    assert torch.equal(a, b)
    assert gaussians_at(static, None)[0] is static.means


def test_ply_round_trip_and_3d_reader_ignores_temporal_fields(tmp_path):
    m = _random_model(n=7)
    path = tmp_path / "st.ply"
    write_gaussian_ply(path, m.to_ply())
    ply = read_gaussian_ply(path)
    assert set(PLY_TEMPORAL_FIELDS) <= set(ply.extra)
    back = model_from_ply(ply)
    assert isinstance(back, SpacetimeModel)
    for name, value in m.params.items():
        torch.testing.assert_close(back.params[name], value.detach(), msg=name)
    # a 3D reader takes the same file as the 3D Gaussians at each temporal centre
    static = GaussianModel.from_ply(ply)
    torch.testing.assert_close(static.means, m.means.detach())
    header = path.read_bytes().split(b"end_header")[0].decode()
    assert "property float t_center" in header and "property float motion_8" in header


def test_static_model_carries_no_temporal_fields(tmp_path):
    static = GaussianModel.from_points(np.zeros((3, 3)) + np.arange(3)[:, None], None, 0)
    assert not any(k in static.params for k in ("t_center", "motion"))
    path = tmp_path / "s.ply"
    write_gaussian_ply(path, static.to_ply())
    ply = read_gaussian_ply(path)
    assert not is_spacetime_ply(ply) and type(model_from_ply(ply)) is GaussianModel
    with pytest.raises(GsgsError, match="no temporal fields"):
        SpacetimeModel.from_ply(ply)


def test_from_points_needs_times_and_sizes_per_frame():
    pts = np.concatenate([np.eye(3), np.eye(3) + 0.01])
    with pytest.raises(GsgsError, match="time per point"):
        SpacetimeModel.from_points(pts, None, 0)
    m = SpacetimeModel.from_points(pts, None, 0, times=np.repeat([0.0, 1.0], 3), t_scale=0.2)
    assert torch.allclose(m.t_center.detach(), torch.tensor([0.0, 0.0, 0.0, 1.0, 1.0, 1.0]))
    assert torch.allclose(m.t_scale, torch.full((6,), 0.2))
    # each frame's copy of the surface is sized by its own frame (distance ~1.41), not by the 0.01
    # offset to the same point in the other frame
    assert float(m.scales.detach().min()) > 0.5
