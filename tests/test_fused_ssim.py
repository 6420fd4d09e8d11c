"""The compiled SSIM of the training loss against metrics.ssim (the 3DGS definition), value and gradient."""

from __future__ import annotations

import pytest
import torch

from gsgs_engine.metrics import ssim
from gsgs_engine.render import cpu_backend
from gsgs_engine.train.fused_ssim import ssim_mean
from gsgs_engine.train.losses import dssim_loss


@pytest.fixture(scope="module", autouse=True)
def _kernel():
    if not cpu_backend.available():
        pytest.skip(f"compiled CPU kernel unavailable: {cpu_backend.unavailable_reason()}")


def _pair(h, w, dtype, seed=0, noise=0.2):
    g = torch.Generator().manual_seed(seed)
    target = torch.rand(h, w, 3, generator=g, dtype=torch.float64)
    img = (target + noise * torch.randn(h, w, 3, generator=g, dtype=torch.float64)).clamp(0, 1)
    return img.to(dtype), target.to(dtype)


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-12), (torch.float32, 2e-6)])
@pytest.mark.parametrize("size", [(37, 23), (5, 3), (1, 1), (2, 40), (64, 48)])
def test_value_and_gradient_match_metrics_ssim(dtype, tol, size):
    img, target = _pair(*size, dtype, seed=size[0])
    a, b = img.clone().requires_grad_(), img.clone().requires_grad_()
    want, got = ssim(a, target), ssim_mean(b, target)
    assert got is not None
    assert abs(float(got.detach()) - float(want.detach())) <= tol
    want.backward()
    got.backward()
    assert torch.isfinite(b.grad).all()
    assert float((a.grad - b.grad).norm() / a.grad.norm().clamp_min(1e-30)) <= 10 * tol


def test_flat_and_anticorrelated_images_stay_finite():
    # flat images: sigma = 0 everywhere; an inverted copy: s12 < 0, so 2 s12 + C2 can cross zero
    flat = torch.full((20, 30, 3), 0.5, dtype=torch.float64)
    target = torch.rand(20, 30, 3, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    for img, tgt in ((flat, flat), (1 - target, target), (flat, target)):
        a, b = img.clone().requires_grad_(), img.clone().requires_grad_()
        want, got = ssim(a, tgt), ssim_mean(b, tgt)
        want.backward()
        got.backward()
        assert torch.isfinite(b.grad).all()
        assert abs(float(got.detach()) - float(want.detach())) < 1e-12
        assert torch.allclose(a.grad, b.grad, atol=1e-12, rtol=1e-9)


def test_dssim_loss_uses_it_and_falls_back_where_it_cannot():
    img, target = _pair(16, 16, torch.float32)
    assert ssim_mean(img, target.clone().requires_grad_()) is None  # gradient to the target: torch path
    assert ssim_mean(img[None], target[None]) is None  # not [H, W, C]
    loss = dssim_loss(img.clone().requires_grad_(), target)
    assert abs(float(loss.detach()) - (1 - float(ssim(img, target)))) < 1e-6


def test_thread_count_does_not_change_the_result():
    img, target = _pair(90, 70, torch.float32, seed=3)
    before = torch.get_num_threads()
    results = []
    try:
        for threads in (1, 2):
            torch.set_num_threads(threads)
            x = img.clone().requires_grad_()
            value = ssim_mean(x, target)
            value.backward()
            results.append((value.detach(), x.grad))
    finally:
        torch.set_num_threads(before)
    assert torch.equal(results[0][0], results[1][0]) and torch.equal(results[0][1], results[1][1])


def _torch_masked(img, target, mask):
    """losses.dssim_loss's torch form of the masked SSIM: the channel-mean map's masked mean."""
    from gsgs_engine.metrics import ssim_map

    m = mask.to(img.dtype)
    return (ssim_map(img, target)[0].mean(dim=0) * m).sum() / m.sum().clamp_min(1.0)


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-12), (torch.float32, 2e-6)])
def test_masked_value_and_gradient_match_the_torch_form(dtype, tol):
    """Pseudo views' masked D-SSIM: hard, soft, sparse (sum below 1: the clamp) and empty masks."""
    img, target = _pair(45, 38, dtype, seed=7)
    g = torch.Generator().manual_seed(8)
    masks = {"hard": torch.rand(45, 38, generator=g) > 0.4, "soft": torch.rand(45, 38, generator=g),
             "sparse": torch.zeros(45, 38), "empty": torch.zeros(45, 38)}
    masks["sparse"][3, 4] = 0.3
    for name, mask in masks.items():
        a, b = img.clone().requires_grad_(), img.clone().requires_grad_()
        want, got = _torch_masked(a, target, mask), ssim_mean(b, target, mask)
        assert got is not None
        assert abs(float(got.detach()) - float(want.detach())) <= tol, name
        want.backward()
        got.backward()
        assert torch.isfinite(b.grad).all(), name
        if name == "empty":
            assert float(got.detach()) == 0.0 and torch.all(b.grad == 0)
        else:
            assert float((a.grad - b.grad).norm() / a.grad.norm().clamp_min(1e-30)) <= 10 * tol, name
    # an all-ones mask is the unmasked mean, to the bit
    x, y = img.clone().requires_grad_(), img.clone().requires_grad_()
    plain, ones = ssim_mean(x, target), ssim_mean(y, target, torch.ones(45, 38))
    plain.backward()
    ones.backward()
    assert torch.equal(plain.detach(), ones.detach()) and torch.equal(x.grad, y.grad)
    # dssim_loss takes the compiled path for a mask too
    loss = dssim_loss(img.clone().requires_grad_(), target, masks["soft"])
    assert abs(float(loss.detach()) - (1 - float(_torch_masked(img, target, masks["soft"])))) <= tol
