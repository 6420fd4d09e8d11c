"""Photometric terms of eq. 11, with and without a pseudo target's confidence mask."""

import torch

from gsgs_engine.metrics import ssim, ssim_map
from gsgs_engine.train.densify import DensifyStats
from gsgs_engine.train.losses import dssim_loss, l1_loss, photometric_terms


def test_masked_terms_see_only_the_masked_pixels():
    g = torch.Generator().manual_seed(0)
    target = torch.rand(24, 32, 3, generator=g)
    render = target.clone()
    render[:, 16:] = 1.0 - render[:, 16:]  # wrong on the right half only
    left = torch.zeros(24, 32)
    left[:, :16] = 1.0
    assert l1_loss(render, target, left) == 0.0
    assert l1_loss(render, target) > 0.1
    # the SSIM window reaches 5 px over the border: compare against the same map's left part
    assert torch.isclose(dssim_loss(render, target, left), 1.0 - ssim_map(render, target)[0].mean(0)[:, :16].mean())
    assert dssim_loss(render, target, left) < dssim_loss(render, target)
    # without a mask (or an all-ones one) the terms are the plain means
    ones = torch.ones(24, 32)
    assert torch.isclose(l1_loss(render, target, ones), l1_loss(render, target))
    assert torch.isclose(dssim_loss(render, target), 1.0 - ssim(render, target))
    # an empty mask contributes nothing and stays finite, gradients included
    r = render.clone().requires_grad_(True)
    terms = photometric_terms(r, target, 0.2, mask=torch.zeros(24, 32))
    total = sum(w * v for w, v in terms.values())
    total.backward()
    assert torch.isfinite(total) and torch.isfinite(r.grad).all() and float(r.grad.abs().sum()) == 0.0


def test_densify_stats_grow_for_appended_gaussians():
    stats = DensifyStats(3)
    stats.grad_accum += 1.0
    stats.denom += 2.0
    stats.grow(2)
    assert stats.grad_accum.tolist() == [1.0, 1.0, 1.0, 0.0, 0.0]
    assert stats.denom.shape == stats.max_radii.shape == (5,)
