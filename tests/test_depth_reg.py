"""Eq. 8-10: normalised depth maps and -MS-SSIM, safe on flat maps, tiny images and sign traps."""

import pytest
import torch

from gsgs_engine.priors.depth_reg import (depth_regulariser, inverse_depth, ms_ssim, ms_ssim_scales,
                                          normalise_depth)


def _smooth_map(h, w, seed=0):
    g = torch.Generator().manual_seed(seed)
    base = torch.rand(1, 1, max(2, h // 4), max(2, w // 4), generator=g, dtype=torch.float64)
    return torch.nn.functional.interpolate(base, size=(h, w), mode="bilinear", align_corners=False)[0, 0] + 1.0


@pytest.mark.parametrize("size", [(1, 1), (2, 3), (7, 5), (16, 16), (33, 20), (64, 64), (200, 180)])
def test_identical_maps_give_minus_one(size):
    d = _smooth_map(*size)
    loss = depth_regulariser(d, d.clone())
    assert torch.isfinite(loss)
    assert loss.item() == pytest.approx(-1.0, abs=1e-6)


@pytest.mark.parametrize("size", [(1, 1), (3, 3), (11, 11), (64, 64)])
def test_flat_and_constant_maps_have_finite_gradients(size):
    flat = torch.full(size, 2.5, dtype=torch.float64, requires_grad=True)
    target = _smooth_map(*size)
    for a, b in ((flat, target), (flat, torch.zeros(size, dtype=torch.float64))):
        loss = depth_regulariser(a, b)
        (g,) = torch.autograd.grad(loss, a)
        assert torch.isfinite(loss) and torch.isfinite(g).all()


def test_normalised_map_has_zero_mean_unit_std_and_flat_map_is_zero():
    d = _smooth_map(32, 24)
    n = normalise_depth(d)
    assert n.mean().abs() < 1e-9 and (n.std(unbiased=False) - 1).abs() < 1e-6
    assert torch.count_nonzero(normalise_depth(torch.ones(5, 5))) == 0


def test_anticorrelated_maps_are_penalised_and_gradient_improves_them():
    # The sign trap: depth and inverse depth are anticorrelated; comparing them unconverted
    # must score worse than comparing like with like.
    depth = _smooth_map(48, 48, seed=3)
    inv = 1.0 / depth
    assert depth_regulariser(inv, inv) < depth_regulariser(depth, inv)
    rendered = inverse_depth(depth.clone().requires_grad_(True))
    x = (1.0 / depth).clone() + 0.3 * _smooth_map(48, 48, seed=9)
    x.requires_grad_(True)
    loss0 = depth_regulariser(x, inv)
    (g,) = torch.autograd.grad(loss0, x)
    loss1 = depth_regulariser((x - 5.0 * g).detach(), inv)
    assert torch.isfinite(rendered).all() and loss1 < loss0


def test_negative_contrast_terms_stay_finite():
    a = _smooth_map(64, 64, seed=1).requires_grad_(True)
    b = -a.detach()  # perfectly anticorrelated: cs < 0 at every scale
    loss = depth_regulariser(a, b)
    (g,) = torch.autograd.grad(loss, a)
    assert torch.isfinite(loss) and torch.isfinite(g).all()
    assert loss.item() > -0.5


def test_scales_follow_image_size():
    assert ms_ssim_scales(200, 200) == (5, 11)
    assert ms_ssim_scales(160, 300)[0] == 4
    assert ms_ssim_scales(20, 20) == (1, 11)
    assert ms_ssim_scales(1, 1) == (1, 1)
    assert ms_ssim_scales(6, 9) == (1, 5)


def test_inverse_depth_of_empty_pixels_is_zero_and_float16_is_upcast():
    depth = torch.tensor([[2.0, 0.0]])
    alpha = torch.tensor([[1.0, 0.0]])
    inv = inverse_depth(depth, alpha)
    assert inv[0, 0].item() == pytest.approx(0.5) and inv[0, 1].item() == 0.0
    h = _smooth_map(32, 32).half()
    assert torch.isfinite(ms_ssim(h, h)) and ms_ssim(h, h).item() == pytest.approx(1.0, abs=1e-3)


def test_masked_regulariser_ignores_outside():
    a = _smooth_map(40, 40, seed=4)
    b = a.clone()
    mask = torch.zeros(40, 40, dtype=torch.bool)
    mask[:, :20] = True
    b[:, 20:] = 100.0 * torch.rand(40, 20, dtype=torch.float64)
    assert depth_regulariser(a, b, mask) < depth_regulariser(a, b)
