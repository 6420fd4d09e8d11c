"""The compiled binocular term (csrc/binocular_cpu.cpp via train/fused_binocular.py) against its torch form
(warp_shifted_to_view + masked_l1): value, mask and gradients; thread counts; non-finite and degenerate inputs."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from gsgs_engine.cameras import Camera
from gsgs_engine.render import cpu_backend
from gsgs_engine.train.fused_binocular import binocular_l1
from gsgs_engine.train.techniques.binocular import (MIN_OPAQUE, masked_l1, shifted_camera, surface_depth,
                                                    warp_shifted_to_view)


def _kernel():
    if not cpu_backend.available():
        pytest.skip(f"compiled CPU kernel unavailable: {cpu_backend.unavailable_reason()}")


def _camera(w: int, h: int) -> Camera:
    return Camera(R=np.eye(3), t=np.array([0.1, -0.2, 0.3]), fx=1.1 * w, fy=1.05 * w, cx=w / 2 + 0.3, cy=h / 2 - 0.2,
                  width=w, height=h)


def _inputs(w, h, scale, baseline, seed=0, target_offset=0.0):
    g = torch.Generator().manual_seed(seed)
    cam = _camera(w, h)
    shifted = shifted_camera(cam, baseline)
    if scale != 1.0:
        shifted = shifted.scaled(scale)
    image = torch.rand(shifted.height, shifted.width, 3, generator=g)
    alpha = 1.2 * torch.rand(h, w, generator=g)
    depth = (2.0 + torch.rand(h, w, generator=g)) * alpha
    target = torch.rand(h, w, 3, generator=g) + target_offset
    return cam, shifted, image, depth, alpha, target


def _both(cam, shifted, image, depth, alpha, target):
    """(loss, mask, d image, d depth, d alpha) of the torch form, then of the compiled one."""
    out = []
    for fused in (False, True):
        img, dep, alp = (t.clone().requires_grad_(True) for t in (image, depth, alpha))
        z = surface_depth(dep, alp)
        if fused:
            loss, mask = binocular_l1(cam, z, shifted, img, target, alp, MIN_OPAQUE)
        else:
            warped, valid = warp_shifted_to_view(cam, z, shifted, img)
            mask = valid & (alp.detach() > MIN_OPAQUE)
            loss = masked_l1(warped, target, mask)
        loss.backward()
        out.append((loss.detach(), mask, img.grad, dep.grad, alp.grad))
    return out


@pytest.mark.parametrize("scale,baseline", [(1.0, 0.3), (1.0, -0.3), (0.5, 0.25), (0.5, -0.8)])
def test_value_mask_and_gradients_match_the_torch_form(scale, baseline):
    """Residuals all of one sign (the target above every sample), so no |d| sits at its kink: the gradients agree to
    float rounding (coordinates are computed in a different order, so not to the bit)."""
    _kernel()
    ref, got = _both(*_inputs(48, 36, scale, baseline, target_offset=1.5))
    assert 0.2 < got[1].float().mean() < 0.9  # some pixels fall outside the shifted view or are transparent
    assert torch.equal(got[1], ref[1])
    torch.testing.assert_close(got[0], ref[0], rtol=1e-6, atol=0)
    for a, b in zip(got[2:], ref[2:]):
        assert a.abs().max() > 0
        torch.testing.assert_close(a, b, rtol=0, atol=2e-5 * float(b.abs().max()))


def test_mixed_sign_residuals_match_in_value():
    _kernel()
    ref, got = _both(*_inputs(64, 40, 1.0, 0.2, seed=4))
    torch.testing.assert_close(got[0], ref[0], rtol=1e-6, atol=0)
    assert torch.equal(got[1], ref[1])
    # a residual within rounding of 0 may take the other sign; every other pixel's gradient agrees
    for a, b in zip(got[2:4], ref[2:4]):
        close = (a - b).abs() <= 1e-5 * float(b.abs().max())
        assert close.float().mean() > 0.99


def test_thread_count_does_not_change_the_result():
    _kernel()
    cam, shifted, image, depth, alpha, target = _inputs(67, 45, 0.5, -0.4, seed=2)
    z = surface_depth(depth, alpha)
    coeffs = (cam.fx, cam.cx, cam.fy, cam.cy, shifted.fx, shifted.cx, shifted.fy, shifted.cy, 0.4, MIN_OPAQUE)
    before = torch.get_num_threads()
    results = []
    try:
        for n in (1, 2, 3):
            torch.set_num_threads(n)
            results.append(cpu_backend._ops().binocular_l1(image, z.contiguous(), target, alpha, *coeffs))
    finally:
        torch.set_num_threads(before)
    for r in results[1:]:
        for a, b in zip(r, results[0]):
            assert torch.equal(a, b)


def test_non_finite_and_non_positive_depths_are_masked_out_with_zero_gradient():
    _kernel()
    cam, shifted, image, _, alpha, target = _inputs(40, 30, 1.0, 0.3, seed=5)
    alpha = torch.ones_like(alpha)
    z = torch.full((30, 40), 3.0)
    bad = {(0, 0): float("nan"), (0, 1): float("inf"), (0, 2): float("-inf"), (1, 0): 0.0, (1, 1): -2.0, (1, 2): 1e-9}
    for (y, x), v in bad.items():
        z[y, x] = v
    z.requires_grad_(True)
    img = image.clone().requires_grad_(True)
    loss, mask = binocular_l1(cam, z, shifted, img, target, alpha, MIN_OPAQUE)
    loss.backward()
    assert torch.isfinite(loss) and torch.isfinite(img.grad).all() and torch.isfinite(z.grad).all()
    for (y, x), v in bad.items():
        if v != float("inf"):  # +inf: no disparity, a valid sample at the pixel's own column
            assert not mask[y, x]
            assert z.grad[y, x] == 0
    assert mask[0, 1] and z.grad[0, 1] == 0  # d ix / dz = b / z^2 = 0 at infinity


@pytest.mark.parametrize("hs,ws", [(1, 1), (1, 7), (5, 1), (2, 2)])
def test_tiny_shifted_images_stay_in_bounds_and_match(hs, ws):
    """One-pixel-wide or -high shifted renders: the clamped taps and the missing right / lower neighbours."""
    _kernel()
    g = torch.Generator().manual_seed(7)
    cam = _camera(9, 6)
    shifted = shifted_camera(cam, 0.05)
    shifted = Camera(R=shifted.R, t=shifted.t, fx=shifted.fx * ws / 9, fy=shifted.fy * hs / 6,
                     cx=shifted.cx * ws / 9, cy=shifted.cy * hs / 6, width=ws, height=hs)
    image = torch.rand(hs, ws, 3, generator=g)
    alpha = torch.ones(6, 9)
    depth = 2.0 + torch.rand(6, 9, generator=g)
    target = torch.rand(6, 9, 3, generator=g) + 1.5
    ref, got = _both(cam, shifted, image, depth, alpha, target)
    assert torch.equal(got[1], ref[1])
    torch.testing.assert_close(got[0], ref[0], rtol=1e-6, atol=0)
    for a, b in zip(got[2:], ref[2:]):
        assert torch.isfinite(a).all()
        torch.testing.assert_close(a, b, rtol=0, atol=2e-5 * max(float(b.abs().max()), 1e-12))


def test_falls_back_where_it_does_not_apply():
    _kernel()
    cam, shifted, image, depth, alpha, target = _inputs(16, 12, 1.0, 0.2)
    z = surface_depth(depth, alpha)
    assert binocular_l1(cam, z.double(), shifted, image.double(), target.double(), alpha.double(), 0.5) is None
    rotated = Camera(R=np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), t=shifted.t, fx=shifted.fx,
                     fy=shifted.fy, cx=shifted.cx, cy=shifted.cy, width=shifted.width, height=shifted.height)
    assert binocular_l1(cam, z, rotated, image, target, alpha, 0.5) is None  # not a pure x shift
    moved = Camera(R=shifted.R, t=np.asarray(shifted.t) + np.array([0.0, 0.1, 0.0]), fx=shifted.fx, fy=shifted.fy,
                   cx=shifted.cx, cy=shifted.cy, width=shifted.width, height=shifted.height)
    assert binocular_l1(cam, z, moved, image, target, alpha, 0.5) is None


def test_bad_shapes_raise_a_clear_error():
    _kernel()
    ops = cpu_backend._ops()
    good = (torch.rand(4, 5, 3), torch.rand(4, 5), torch.rand(4, 5, 3), torch.rand(4, 5))
    coeffs = (5.0, 2.5, 5.0, 2.0, 5.0, 2.5, 5.0, 2.0, 0.1, 0.5)
    with pytest.raises(RuntimeError, match="binocular_l1"):
        ops.binocular_l1(good[0], torch.rand(4, 6), good[2], good[3], *coeffs)
    with pytest.raises(RuntimeError, match="float32"):
        ops.binocular_l1(good[0].double(), *good[1:], *coeffs)
    with pytest.raises(RuntimeError, match="focal"):
        ops.binocular_l1(*good, 0.0, *coeffs[1:])
