"""PSNR / SSIM against direct float64 computations; LPIPS reports absence instead of a number
(the real LPIPS values are checked in test_lpips.py)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from gsgs_engine import GsgsError
from gsgs_engine.metrics import lpips_or_none, psnr, ssim


def pair(h: int, w: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    rng = np.random.default_rng(seed)
    gt = rng.uniform(0.1, 0.9, size=(h, w, 3))
    img = np.clip(gt + rng.normal(0, 0.15, size=gt.shape), 0, 1)
    return torch.tensor(img, dtype=torch.float32), torch.tensor(gt, dtype=torch.float32)


def ssim_direct(img: np.ndarray, gt: np.ndarray) -> float:
    """SSIM by explicit float64 window sums with zero padding (3DGS: conv2d padding=5, 11x11, sigma 1.5)."""
    x, y = img.astype(np.float64), gt.astype(np.float64)
    g = np.exp(-((np.arange(11) - 5) ** 2) / (2 * 1.5**2))
    window = np.outer(g, g) / g.sum() ** 2
    h, w, _ = x.shape

    def blur(a):
        padded = np.pad(a, ((5, 5), (5, 5), (0, 0)))
        out = np.zeros_like(a)
        for dy in range(11):
            for dx in range(11):
                out += window[dy, dx] * padded[dy:dy + h, dx:dx + w]
        return out

    mu1, mu2 = blur(x), blur(y)
    s11, s22, s12 = blur(x * x) - mu1**2, blur(y * y) - mu2**2, blur(x * y) - mu1 * mu2
    c1, c2 = 0.01**2, 0.03**2
    return float(np.mean((2 * mu1 * mu2 + c1) * (2 * s12 + c2) / ((mu1**2 + mu2**2 + c1) * (s11 + s22 + c2))))


def test_identical_images():
    img, _ = pair(16, 20)
    assert torch.isinf(psnr(img, img.clone())) and psnr(img, img.clone()) > 0
    assert float(ssim(img, img.clone())) == pytest.approx(1.0, abs=1e-6)


def test_psnr_of_a_constant_offset():
    _, gt = pair(12, 10)
    assert float(psnr(gt + 0.1, gt)) == pytest.approx(20.0, abs=1e-3)  # mse 0.01 -> 20 dB
    assert float(psnr(gt - 0.01, gt)) == pytest.approx(40.0, abs=1e-2)


def test_ssim_matches_direct_float64():
    img, gt = pair(13, 17, seed=1)
    expected = ssim_direct(img.numpy(), gt.numpy())
    assert float(ssim(img, gt)) == pytest.approx(expected, abs=1e-5)
    assert float(ssim(img.double(), gt.double())) == pytest.approx(expected, abs=1e-12)
    assert 0.2 < expected < 0.95  # a pair that actually differs


def test_layouts_batches_and_numpy_agree():
    a, b = pair(9, 11, seed=2)
    c, d = pair(9, 11, seed=3)
    batch_x = torch.stack([a, c]).permute(0, 3, 1, 2)
    batch_y = torch.stack([b, d]).permute(0, 3, 1, 2)
    assert float(ssim(batch_x, batch_y)) == pytest.approx((float(ssim(a, b)) + float(ssim(c, d))) / 2, abs=1e-6)
    assert float(psnr(batch_x, batch_y)) == pytest.approx((float(psnr(a, b)) + float(psnr(c, d))) / 2, abs=1e-4)
    assert float(ssim(a.numpy(), b.numpy())) == pytest.approx(float(ssim(a, b)), abs=1e-7)


@pytest.mark.parametrize("h,w", [(1, 1), (5, 7), (2, 40)])
def test_images_smaller_than_the_window(h, w):
    img, gt = pair(h, w, seed=4)
    value = float(ssim(img, gt))
    assert np.isfinite(value) and value == pytest.approx(ssim_direct(img.numpy(), gt.numpy()), abs=1e-5)
    assert float(ssim(gt, gt)) == pytest.approx(1.0, abs=1e-6)


def test_gradients_are_finite():
    img, gt = pair(10, 12, seed=5)
    img.requires_grad_(True)
    (1 - ssim(img, gt)).backward()
    grad_ssim = img.grad.clone()
    img.grad = None
    (-psnr(img, gt)).backward()
    for grad in (grad_ssim, img.grad):
        assert torch.isfinite(grad).all() and grad.abs().sum() > 0
    # the gradient points the right way: a small step against it raises SSIM
    with torch.no_grad():
        stepped = img - 1e-2 * grad_ssim / grad_ssim.abs().max()
    assert float(ssim(stepped, gt)) > float(ssim(img.detach(), gt))


def test_bad_inputs():
    a, b = pair(4, 5)
    with pytest.raises(GsgsError, match="differs from ground-truth shape"):
        psnr(a, b[:3])
    with pytest.raises(GsgsError, match="must be float"):
        ssim((a * 255).to(torch.uint8), (b * 255).to(torch.uint8))
    with pytest.raises(GsgsError, match=r"\[H, W, C\] or \[B, C, H, W\]"):
        psnr(a[:, :, 0], b[:, :, 0])


def test_lpips_absent_weights_give_none_with_reason(tmp_path):
    a, b = pair(8, 8)
    for net in ("vgg", "alex"):
        value, reason = lpips_or_none(a, b, net=net, cache=tmp_path / "empty")
        assert value is None and reason.startswith("LPIPS weights not available") and "gsgs_engine.lpips.fetch" in reason
    with pytest.raises(GsgsError, match="unknown LPIPS network"):
        lpips_or_none(a, b, net="squeeze", cache=tmp_path)
