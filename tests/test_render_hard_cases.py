"""Hard inputs for render(): each case checks finite outputs, finite gradients and the right
behaviour, on every backend available here (unavailable ones skip with the reason)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera
from gsgs_engine.render import api, render, rgb_to_sh0


@pytest.fixture(autouse=True)
def _single_thread():
    # Tiny tensors: OpenMP threads only add synchronisation on a loaded 2-core machine.
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(params=["reference", "cpu"])
def backend(request):
    ok, reason = api.available_backends()[request.param]
    if not ok:
        pytest.skip(f"backend {request.param!r} unavailable: {reason}")
    return request.param


def axis_camera(width=64, height=48, f=60.0, cx=None, cy=None, z=4.0):
    """Looks down +z from (0, 0, -z): a world point (0, 0, 0) is at depth z on the optical axis."""
    return Camera(R=np.eye(3), t=np.array([0.0, 0.0, z]), fx=f, fy=f, cx=width / 2 if cx is None else cx,
                  cy=height / 2 if cy is None else cy, width=width, height=height)


def gaussians(means, scales=0.2, opacities=0.7, colors=None, quats=None, dtype=torch.float32, sh_degree=0):
    means = torch.as_tensor(means, dtype=dtype).reshape(-1, 3)
    n = means.shape[0]
    scales = torch.as_tensor(scales, dtype=dtype).expand(n, 3).clone()  # a number, [1, 3] or [N, 3]
    opacities = torch.as_tensor(opacities, dtype=dtype).expand(n).clone()
    quats = torch.tensor([[1.0, 0, 0, 0]], dtype=dtype).expand(n, 4).clone() if quats is None \
        else torch.as_tensor(quats, dtype=dtype).reshape(n, 4)
    rgb = torch.full((n, 3), 0.6, dtype=dtype) if colors is None else torch.as_tensor(colors, dtype=dtype).reshape(n, 3)
    sh = torch.zeros(n, (sh_degree + 1) ** 2, 3, dtype=dtype)
    sh[:, 0] = rgb_to_sh0(rgb)
    if sh_degree > 0:
        sh[:, 1:] = 0.05
    return [means, quats, scales, opacities, sh]


def render_and_backward(inputs, camera, backend, sh_degree=0, background=(0.1, 0.2, 0.3), near=0.01, far=1e10):
    """Render with every input (and the background) as a leaf; backprop a loss using all outputs."""
    leaves = [x.detach().clone().requires_grad_() for x in inputs]
    bg = torch.tensor(background, dtype=torch.float64 if inputs[0].dtype == torch.float64 else torch.float32,
                      requires_grad=True)
    out = render(*leaves, camera, sh_degree, bg, backend=backend, near=near, far=far)
    for name in ("color", "depth", "alpha"):
        assert torch.isfinite(getattr(out, name)).all(), f"{name} has NaN/Inf"
    loss = (out.color * torch.tensor([0.3, 0.5, 0.7], dtype=out.color.dtype)).sum() + 0.1 * out.depth.sum() \
        + out.alpha.sum()
    loss.backward()
    grads = [torch.zeros_like(x) if x.grad is None else x.grad for x in leaves]
    for g in grads + [bg.grad]:
        assert torch.isfinite(g).all(), "a gradient has NaN/Inf"
    return out, grads


def test_behind_camera_on_near_plane_and_beyond_far_are_culled(backend):
    # camera at the origin looking down +z: a mean's z is its depth
    cam = Camera(R=np.eye(3), t=np.zeros(3), fx=60.0, fy=60.0, cx=32.0, cy=24.0, width=64, height=48)
    means = [[0.0, 0.0, -1.0],   # behind
             [0.0, 0.0, 0.0],    # at the camera centre (zero view direction for SH)
             [0.01, 0.0, 0.01],  # on the near plane
             [0.0, 0.0, 1e-9],   # in front of the camera, closer than near
             [0.0, 0.0, 20.0],   # beyond far
             [0.1, 0.0, 3.0]]    # visible
    # anisotropic, so that the rotation has a gradient too
    inputs = gaussians(means, scales=torch.tensor([[0.3, 0.2, 0.1]]).expand(6, 3), sh_degree=1)
    out, grads = render_and_backward(inputs, cam, backend, sh_degree=1, near=0.01, far=10.0)
    assert out.radii[:5].tolist() == [0, 0, 0, 0, 0] and not out.visible[:5].any()
    assert out.radii[5] > 0 and out.visible[5]
    for g in grads:
        assert torch.count_nonzero(g[:5]) == 0, "culled Gaussians must get exactly zero gradient"
        assert g[5].abs().sum() > 0
    assert out.means2d.grad is not None and torch.count_nonzero(out.means2d.grad[:5]) == 0


@pytest.mark.parametrize("scale", [0.0, 1e-40, 1e6])
def test_zero_denormal_and_huge_scales(backend, scale):
    cam = axis_camera(cx=32.5, cy=24.5)  # the mean projects onto pixel (32, 24)'s centre
    inputs = gaussians([[0.0, 0.0, 0.0], [0.5, 0.3, 0.5]], scales=torch.tensor([[scale] * 3, [0.1] * 3]),
                       opacities=0.7)
    assert scale == 0 or scale >= 1 or inputs[2][0, 0].item() != 0  # the denormal survives as float32
    out, grads = render_and_backward(inputs, cam, backend)
    assert out.visible.all()
    if scale < 1:
        # a point: only the 0.3 px^2 low-pass dilation remains, radius ceil(3 sqrt(0.3)) = 2
        assert int(out.radii[0]) == 2
        assert out.alpha[24, 32].item() == pytest.approx(0.7, rel=1e-5)
        assert out.alpha[24, 33].item() == pytest.approx(0.7 * math.exp(-0.5 / 0.3), rel=1e-4)
        assert out.alpha[24, 34].item() == 0.0  # 0.7 exp(-0.5 * 4 / 0.3) < 1/255: skipped
    else:
        # fills the view: alpha ~ opacity at every pixel (over the second Gaussian, which it occludes)
        assert out.alpha.min().item() == pytest.approx(0.7, abs=1e-3)


def test_nearly_singular_2d_covariance(backend):
    # a needle 1e4 long and 1e-8 thin, along the image diagonal: singular before dilation
    c, s = math.cos(math.pi / 8), math.sin(math.pi / 8)  # quaternion of a 45 degree turn about z
    inputs = gaussians([[0.0, 0.0, 0.0]], scales=torch.tensor([[1e4, 1e-8, 1e-8]]), opacities=0.5,
                       quats=[[c, 0.0, 0.0, s]])
    cam = axis_camera(cx=32.5, cy=24.5)
    out, _ = render_and_backward(inputs, cam, backend)
    assert out.visible.all()
    # along the needle the profile is flat; across it only the dilation (variance 0.3) remains
    for d in (-10, -3, 0, 5, 12):
        assert out.alpha[24 + d, 32 + d].item() == pytest.approx(0.5, rel=1e-3)
    # one pixel to the right is 1/sqrt(2) px from the needle's axis
    assert out.alpha[24, 33].item() == pytest.approx(0.5 * math.exp(-0.5 * 0.5 / 0.3), rel=1e-3)


def test_zero_quaternion_is_identity_rotation(backend):
    cam = axis_camera()
    means = [[0.1, -0.2, 0.0], [-0.3, 0.1, 0.2]]
    scales = torch.tensor([[0.4, 0.1, 0.2], [0.1, 0.3, 0.2]])
    zero_q = gaussians(means, scales=scales, quats=[[0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]])
    ident_q = gaussians(means, scales=scales, quats=[[1.0, 0.0, 0.0, 0.0], [2.0, 0.0, 0.0, 0.0]])
    out0, grads0 = render_and_backward(zero_q, cam, backend)
    out1, _ = render_and_backward(ident_q, cam, backend)
    torch.testing.assert_close(out0.color, out1.color)
    torch.testing.assert_close(out0.alpha, out1.alpha)
    assert out0.alpha.max() > 0.5


def test_saturated_opacity_logits(backend):
    cam = axis_camera(cx=32.5, cy=24.5)
    logits = torch.tensor([30.0, -30.0], requires_grad=True)
    base = gaussians([[0.0, 0.0, 0.0], [0.4, 0.2, -0.5]], scales=0.2)
    out = render(base[0], base[1], base[2], torch.sigmoid(logits), base[4], cam, 0, torch.ones(3), backend=backend)
    (out.color.sum() + out.alpha.sum()).backward()
    assert torch.isfinite(logits.grad).all() and torch.isfinite(out.color).all()
    assert out.alpha[24, 32].item() == pytest.approx(0.99, abs=1e-6)  # sigmoid(30) == 1, capped at 0.99
    # sigmoid(-30) ~ 1e-13 < 1/255: that Gaussian is skipped everywhere
    alone = render(base[0][:1], base[1][:1], base[2][:1], torch.sigmoid(logits[:1].detach()), base[4][:1], cam, 0,
                   torch.ones(3), backend=backend)
    torch.testing.assert_close(out.color.detach(), alone.color)


def test_one_gaussian_covering_the_whole_image(backend):
    cam = axis_camera(64, 48)
    # sigma = 60 * 1000 / 4 = 15000 px: the profile is flat to 1e-5 over the image
    inputs = gaussians([[0.0, 0.0, 0.0]], scales=1000.0, opacities=0.6, colors=[[0.2, 0.9, 0.4]])
    out, grads = render_and_backward(inputs, cam, backend, background=(1.0, 1.0, 1.0))
    assert int(out.radii[0]) > 64
    torch.testing.assert_close(out.alpha, torch.full((48, 64), 0.6), atol=2e-4, rtol=0)
    want = torch.tensor([0.2, 0.9, 0.4]) * 0.6 + 0.4
    torch.testing.assert_close(out.color, want.expand(48, 64, 3), atol=2e-4, rtol=0)
    torch.testing.assert_close(out.depth, torch.full((48, 64), 4.0 * 0.6), atol=1e-3, rtol=0)
    assert grads[3].abs().sum() > 0


def test_no_gaussians_gives_background(backend):
    cam = axis_camera(37, 21)
    inputs = gaussians(np.zeros((0, 3)))
    out, _ = render_and_backward(inputs, cam, backend, background=(0.25, 0.5, 0.75))
    assert out.color.shape == (21, 37, 3) and out.depth.shape == (21, 37) and out.alpha.shape == (21, 37)
    torch.testing.assert_close(out.color, torch.tensor([0.25, 0.5, 0.75]).expand(21, 37, 3))
    assert torch.count_nonzero(out.alpha) == 0 and torch.count_nonzero(out.depth) == 0
    assert out.radii.shape == (0,) and out.means2d.shape == (0, 2)


@pytest.mark.parametrize("size", [(1, 1), (37, 5), (5, 37), (101, 3)])
def test_tiny_and_non_square_images(backend, size):
    width, height = size
    cam = axis_camera(width, height, f=20.0)  # odd sizes: the centred principal point is a pixel centre
    inputs = gaussians([[0.0, 0.0, 0.0]], scales=0.15, opacities=0.8)
    out, _ = render_and_backward(inputs, cam, backend)
    assert out.color.shape == (height, width, 3) and out.alpha.shape == (height, width)
    assert out.alpha[height // 2, width // 2].item() == pytest.approx(0.8, rel=1e-5)


def test_off_centre_principal_point(backend):
    cam = axis_camera(64, 48, cx=10.5, cy=30.5)
    inputs = gaussians([[0.0, 0.0, 0.0]], scales=0.1, opacities=0.9)
    out, _ = render_and_backward(inputs, cam, backend)
    torch.testing.assert_close(out.means2d.detach(), torch.tensor([[10.5, 30.5]]))
    row, col = divmod(int(out.alpha.argmax()), 64)
    assert (row, col) == (30, 10)
    assert out.alpha[30, 10].item() == pytest.approx(0.9, rel=1e-5)


def test_equal_depths_composite_in_index_order_deterministically(backend):
    cam = axis_camera(cx=32.5, cy=24.5)
    red, blue = [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]
    pair = gaussians([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]], scales=0.3, opacities=0.6, colors=[red, blue])
    bg = (1.0, 1.0, 1.0)
    out, _ = render_and_backward(pair, cam, backend, background=bg)
    want = 0.6 * torch.tensor(red) + 0.4 * 0.6 * torch.tensor(blue) + 0.16 * torch.ones(3)
    torch.testing.assert_close(out.color[24, 32], want, atol=1e-6, rtol=0)
    swapped, _ = render_and_backward([x.flip(0) for x in pair], cam, backend, background=bg)
    want_swapped = 0.6 * torch.tensor(blue) + 0.4 * 0.6 * torch.tensor(red) + 0.16 * torch.ones(3)
    torch.testing.assert_close(swapped.color[24, 32], want_swapped, atol=1e-6, rtol=0)
    # many Gaussians in one depth plane (z = 0 for all): bit-identical results, run after run
    g = torch.Generator().manual_seed(5)
    means = torch.cat([torch.rand(40, 2, generator=g) - 0.5, torch.zeros(40, 1)], dim=1)
    many = gaussians(means, scales=0.15, opacities=0.5, colors=torch.rand(40, 3, generator=g))
    first, first_grads = render_and_backward(many, cam, backend)
    again, again_grads = render_and_backward(many, cam, backend)
    assert torch.equal(first.color, again.color) and torch.equal(first.depth, again.depth)
    assert all(torch.equal(a, b) for a, b in zip(first_grads, again_grads))


def test_float64_end_to_end(backend):
    cam = axis_camera()
    inputs = gaussians([[0.1, 0.0, 0.0], [-0.2, 0.1, 0.3]], scales=0.2, dtype=torch.float64, sh_degree=1)
    if backend == "cpu":
        with pytest.raises(GsgsError, match="float32 only"):
            render(*inputs, cam, 1, torch.ones(3), backend="cpu")
        return
    out, grads = render_and_backward(inputs, cam, backend, sh_degree=1)
    assert out.color.dtype == out.depth.dtype == out.alpha.dtype == out.means2d.dtype == torch.float64
    assert all(g.dtype == torch.float64 for g in grads)


def test_float64_auto_uses_reference():
    cam = axis_camera()
    inputs = gaussians([[0.1, 0.0, 0.0]], dtype=torch.float64)
    out = render(*inputs, cam, 0, torch.ones(3), backend="auto")
    assert out.backend == "reference" and out.color.dtype == torch.float64


def test_float16_inputs_are_upcast(backend):
    cam = axis_camera()
    inputs32 = gaussians([[0.1, 0.0, 0.0], [-0.2, 0.1, 0.3]], scales=0.2, sh_degree=1)
    inputs16 = [x.half() for x in inputs32]
    out16, grads16 = render_and_backward(inputs16, cam, backend, sh_degree=1)
    assert out16.color.dtype == torch.float32
    assert all(g.dtype == torch.float16 for g in grads16)  # gradients flow back to the half leaves
    out32, _ = render_and_backward([x.float() for x in inputs16], cam, backend, sh_degree=1)
    torch.testing.assert_close(out16.color, out32.color)
