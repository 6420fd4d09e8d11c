"""Parity of the compiled projection + SH (project_cpu) with the pure-torch oracle (project.py).

float64 runs the same C++ code templated on double: any mistake in the hand-written derivatives
shows far above rounding (1e-10). float32 is what training runs: 1e-5 relative, and through the
whole renderer (images, every parameter gradient and the means2d gradient densification reads).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera
from gsgs_engine.render import cpu_backend
from gsgs_engine.render.api import render
from gsgs_engine.render.project import project_gaussians

FIELDS = ("means2d", "conics", "depths", "colors")


@pytest.fixture(scope="module")
def project_cpu():
    if not cpu_backend.available():
        pytest.skip(f"compiled CPU kernel unavailable: {cpu_backend.unavailable_reason()}")
    from gsgs_engine.render.project_cpu import project_gaussians_cpu
    return project_gaussians_cpu


def tilted_camera(width=64, height=48, f=70.0):
    """A rotated, off-centre camera looking at the origin from about 4 units (R is not the identity)."""
    a, b = 0.3, -0.2
    Ry = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    Rx = np.array([[1, 0, 0], [0, math.cos(b), -math.sin(b)], [0, math.sin(b), math.cos(b)]])
    R = Rx @ Ry
    return Camera(R=R, t=np.array([0.1, -0.2, 4.0]), fx=f, fy=f * 1.1, cx=width * 0.45, cy=height * 0.55,
                  width=width, height=height)


def random_gaussians(seed, n, dtype, spread=2.5, log_scale_sd=1.5):
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=g, dtype=torch.float64) * 2 - 1) * spread  # some behind the camera
    quats = torch.randn(n, 4, generator=g, dtype=torch.float64)
    scales = 0.05 * torch.exp(torch.randn(n, 3, generator=g, dtype=torch.float64) * log_scale_sd)  # tiny to huge
    sh = torch.randn(n, 16, 3, generator=g, dtype=torch.float64) * 0.4
    return [t.to(dtype) for t in (means, quats, scales, sh)]


def project_both(project_cpu, params, camera, degree, seed=0):
    """Both projections with a random loss on the visible Gaussians' outputs (what the rasteriser sends back:
    nothing for a culled one) -> {name: (projection, [grad means, quats, scales, sh])}."""
    results = {}
    for name in ("cpu", "oracle"):
        leaves = [p.clone().requires_grad_(True) for p in params]
        means, quats, scales, sh = leaves
        if name == "cpu":
            p = project_cpu(means, quats, scales, camera, sh, sh_degree=degree)
        else:
            p = project_gaussians(means, quats, scales, camera, sh=sh, sh_degree=degree)
        g = torch.Generator().manual_seed(seed)
        vis = (p.radii > 0).to(means.dtype)
        loss = 0
        for f in FIELDS:
            t = getattr(p, f)
            w = torch.randn(t.shape, generator=g, dtype=torch.float64).to(t.dtype)
            loss = loss + (t * w * (vis if t.dim() == 1 else vis[:, None])).sum()
        loss.backward()
        results[name] = (p, [x.grad for x in leaves])
    return results


def rel(a, b):
    a, b = a.detach().double(), b.detach().double()
    return float((a - b).norm() / b.norm().clamp_min(1e-30))


def check(results, tol, label):
    (pc, gc), (po, go) = results["cpu"], results["oracle"]
    assert torch.equal(pc.radii, po.radii), f"{label}: radii differ"
    assert torch.equal(pc.visible, po.visible)
    vis = po.radii > 0
    for f in FIELDS:
        a, b = getattr(pc, f)[vis], getattr(po, f)[vis]
        assert torch.isfinite(a).all(), f"{label}: {f} not finite"
        assert rel(a, b) <= tol, f"{label}: {f} differs ({rel(a, b):.3g})"
    for name, a, b in zip(("means", "quats", "scales", "sh"), gc, go):
        assert torch.isfinite(a).all(), f"{label}: gradient of {name} not finite"
        # culled rows: exactly zero (the oracle's autograd turns 0 * NaN into NaN for a NaN mean)
        assert torch.all(a[~vis] == 0), f"{label}: a culled Gaussian got a gradient for {name}"
        assert rel(a[vis], b[vis]) <= tol, f"{label}: gradient of {name} differs ({rel(a[vis], b[vis]):.3g})"


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_float64_matches_autograd_of_the_oracle(project_cpu, degree):
    params = random_gaussians(degree, 400, torch.float64)
    results = project_both(project_cpu, params, tilted_camera(), degree, seed=degree)
    visible = int(results["oracle"][0].visible.sum())
    assert 100 < visible < 400, "the scene must mix visible and culled Gaussians"
    check(results, 1e-10, f"float64 degree {degree}")


@pytest.mark.parametrize("degree", [0, 3])
def test_float32_matches_the_oracle(project_cpu, degree):
    params = random_gaussians(10 + degree, 400, torch.float32, log_scale_sd=1.0)
    check(project_both(project_cpu, params, tilted_camera(), degree, seed=5), 1e-5, f"float32 degree {degree}")


def hard_cases(dtype):
    """One Gaussian per row: each a case the projection must survive with finite output and gradient."""
    means = [[0.0, 0.0, 0.0]] * 9 + [[3.9, 0.0, 0.0], [0.0, 0.0, -4.0], [0.0, 0.0, -3.995], [float("nan"), 0, 0]]
    quats = [[1.0, 0.0, 0.0, 0.0]] * 13
    scales = [[0.1, 0.1, 0.1]] * 13
    quats[1] = [0.0, 0.0, 0.0, 0.0]      # zero quaternion: identity rotation, zero gradient
    scales[2] = [0.0, 0.0, 0.0]          # zero scales: the covariance is only the dilation
    scales[3] = [1e-8, 1.0, 1e-8]        # needle
    scales[4] = [1e-9, 1e-9, 1e-9]       # tiny
    scales[5] = [1e4, 1e4, 1e4]          # huge
    scales[6] = [1.0, 1.0, 1e-7]         # flat disk (degenerate 3D covariance)
    quats[7] = [1e-7, 2e-7, 0.0, 1e-7]   # near-zero quaternion (above the clamp)
    quats[8] = [0.0, 0.0, 0.0, 5.0]      # non-unit quaternion
    scales[9] = [1.5, 0.5, 1.0]          # large, so it reaches the view although its mean is outside
    # row 9: far outside the view laterally (tx/tz clamped); row 10: behind; row 11: on the camera centre
    # (the SH direction is zero); row 12: NaN mean
    t = lambda x: torch.tensor(x, dtype=dtype)  # noqa: E731
    sh = torch.full((13, 16, 3), 0.2, dtype=dtype)
    return [t(means), t(quats), t(scales), sh]


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-10), (torch.float32, 1e-5)])
def test_hard_cases_match_the_oracle(project_cpu, dtype, tol):
    cam = Camera(R=np.eye(3), t=np.array([0.0, 0.0, 4.0]), fx=60.0, fy=60.0, cx=32.0, cy=24.0, width=64, height=48)
    params = hard_cases(dtype)
    results = project_both(project_cpu, params, cam, 3, seed=1)
    radii = results["oracle"][0].radii
    assert radii[9] > 0, "the laterally clamped Gaussian must stay visible (it is huge on screen)"
    assert radii[10] == 0 and radii[11] == 0 and radii[12] == 0
    check(results, tol, f"hard cases {dtype}")


def _projection_and_gradients(project_cpu, params, camera, degree):
    leaves = [p.clone().requires_grad_(True) for p in params]
    p = project_cpu(*leaves[:3], camera, leaves[3], sh_degree=degree)
    g = torch.Generator().manual_seed(degree)
    loss = sum((getattr(p, f) * torch.randn(getattr(p, f).shape, generator=g)).sum() for f in FIELDS)
    loss.backward()
    return [p.radii] + [getattr(p, f) for f in FIELDS] + [x.grad for x in leaves]


@pytest.mark.parametrize("degree", [0, 1, 3])
def test_eight_lanes_equal_one_lane_bit_for_bit(project_cpu, degree):
    """float32 projects eight Gaussians at a time; the one-lane code (the same source) must give the same bits,
    hard cases included (zero / NaN / behind / huge / needles), for counts that leave a one-lane tail and SH records
    shorter than, a little longer than and a multiple of the eight fields moved at a time."""
    ops = cpu_backend._ops()
    hard = hard_cases(torch.float32)
    for n, camera in ((403, tilted_camera()), (21, None)):
        params = random_gaussians(20 + degree, n, torch.float32, log_scale_sd=1.0)
        if camera is not None:  # only the coefficients the degree uses: records of 3, 12 or 48 floats
            params[3] = params[3][:, : (degree + 1) ** 2].contiguous()
        if camera is None:  # the hard cases, repeated so they fill whole eight-lane groups
            params = [torch.cat([h] * 2 + [r[: n - 2 * len(h)]]) for h, r in zip(hard, params)]
            camera = Camera(R=np.eye(3), t=np.array([0.0, 0.0, 4.0]), fx=60.0, fy=60.0, cx=32.0, cy=24.0,
                            width=64, height=48)
        previous = ops.project_lane_width(1)
        try:
            one = _projection_and_gradients(project_cpu, params, camera, degree)
        finally:
            ops.project_lane_width(previous)
        assert previous == 8, "eight lanes are the default"
        eight = _projection_and_gradients(project_cpu, params, camera, degree)
        for a, b in zip(one, eight):
            assert torch.equal(torch.nan_to_num(a, nan=7.0), torch.nan_to_num(b, nan=7.0))
            assert torch.equal(torch.isnan(a), torch.isnan(b))


def test_tiny_images(project_cpu):
    for w, h in ((1, 1), (2, 1), (1, 3)):
        cam = Camera(R=np.eye(3), t=np.array([0.0, 0.0, 4.0]), fx=2.0, fy=2.0, cx=w / 2, cy=h / 2, width=w, height=h)
        params = random_gaussians(3, 50, torch.float64, spread=0.5)
        check(project_both(project_cpu, params, cam, 2), 1e-10, f"{w}x{h}")


def _render_grads(backend, params, camera, degree=3, depth_weight=0.05):
    leaves = [p.clone().requires_grad_(True) for p in params]
    out = render(*leaves, camera=camera, sh_degree=degree, background=torch.tensor([0.2, 0.4, 0.6]), backend=backend)
    g = torch.Generator().manual_seed(7)
    loss = ((out.color * torch.rand(out.color.shape, generator=g)).sum() + depth_weight * out.depth.sum()
            + (out.alpha * torch.rand(out.alpha.shape, generator=g)).sum())
    loss.backward()
    return out, [p.grad for p in leaves] + [out.means2d.grad]


def _render_params(seed, n):
    means, quats, scales, sh = random_gaussians(seed, n, torch.float32, spread=1.2, log_scale_sd=0.7)
    opacities = 0.05 + 0.9 * torch.rand(n, generator=torch.Generator().manual_seed(seed))
    return [means, quats, scales, opacities, sh]


@pytest.mark.parametrize("depth_weight", [0.05, 0.0])  # 0: no depth gradient, the kernel skips its terms
def test_render_matches_the_reference_renderer(project_cpu, depth_weight):
    camera, params = tilted_camera(61, 43), _render_params(21, 300)
    out_c, grads_c = _render_grads("cpu", params, camera, depth_weight=depth_weight)
    out_r, grads_r = _render_grads("reference", params, camera, depth_weight=depth_weight)
    assert out_c.backend == "cpu" and int(out_c.visible.sum()) > 150
    for field in ("color", "depth", "alpha"):
        err = float((getattr(out_c, field) - getattr(out_r, field)).detach().abs().max())
        assert err <= 1e-5 * (5.0 if field == "depth" else 1.0), f"{field} differs by {err:.3g}"
    for name, a, b in zip(("means", "quats", "scales", "opacities", "sh", "means2d"), grads_c, grads_r):
        assert torch.isfinite(a).all() and rel(a, b) <= 1e-5, f"gradient of {name} differs ({rel(a, b):.3g})"


def test_render_is_bit_identical_for_any_thread_count(project_cpu):
    camera, params = tilted_camera(96, 80), _render_params(4, 6000)  # several work chunks per thread
    before = torch.get_num_threads()
    runs = []
    try:
        for threads in (1, 2, 3):
            torch.set_num_threads(threads)
            runs.append(_render_grads("cpu", params, camera))
    finally:
        torch.set_num_threads(before)
    (out1, g1) = runs[0]
    for out, g in runs[1:]:
        for field in ("color", "depth", "alpha"):
            assert torch.equal(getattr(out, field), getattr(out1, field)), field
        for a, b in zip(g, g1):
            assert torch.equal(a, b), "a gradient depends on the thread count"


def test_bad_inputs_raise_clear_errors(project_cpu):
    cam = tilted_camera()
    means, quats, scales, sh = random_gaussians(0, 5, torch.float32)
    with pytest.raises(RuntimeError, match="sh_degree"):
        project_cpu(means, quats, scales, cam, sh, sh_degree=4)
    with pytest.raises(RuntimeError, match="coefficients"):
        project_cpu(means, quats, scales, cam, sh[:, :4], sh_degree=2)
    with pytest.raises(RuntimeError, match="quats"):
        project_cpu(means, quats[:, :3], scales, cam, sh, sh_degree=0)


def _split_and_joined(project_cpu, params, camera, degree, rest_len):
    """Projection outputs and gradients with the SH in one tensor of the degree's coefficients, and with the DC
    term and a rest of `rest_len` coefficients (the model's two parameters): [outputs..., grads...] of each."""
    means, quats, scales, sh = params
    dc, rest = sh[:, :1].contiguous(), sh[:, 1:1 + rest_len].contiguous()
    joined = torch.cat([dc, rest[:, : (degree + 1) ** 2 - 1]], dim=1)
    runs = []
    for split in (False, True):
        leaves = [t.clone().requires_grad_(True) for t in ((means, quats, scales, dc, rest) if split
                                                          else (means, quats, scales, joined))]
        if split:
            p = project_cpu(*leaves[:3], camera, leaves[3], sh_degree=degree, sh_rest=leaves[4])
        else:
            p = project_cpu(*leaves[:3], camera, leaves[3], sh_degree=degree)
        g = torch.Generator().manual_seed(degree)
        loss = sum((getattr(p, f) * torch.randn(getattr(p, f).shape, generator=g, dtype=torch.float64)
                    .to(means.dtype)).sum() for f in FIELDS)
        loss.backward()
        grads = [t.grad for t in leaves]
        if split:  # the joined form's SH gradient is the head's and the used part of the rest's
            assert torch.all(grads[4][:, (degree + 1) ** 2 - 1:] == 0), "an unused coefficient got a gradient"
            grads = grads[:3] + [torch.cat([grads[3], grads[4][:, : (degree + 1) ** 2 - 1]], dim=1)]
        runs.append([getattr(p, f) for f in FIELDS] + [p.radii] + grads)
    return runs


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_sh_in_two_parts_equals_one_tensor_bit_for_bit(project_cpu, degree, dtype):
    """The trainer passes its DC and higher-band parameters as they are (`sh_rest`): the same bits as the joined
    tensor GaussianModel.sh() makes, forward and backward, at both lane widths, with a rest as long as the degree
    needs and longer (a model whose active degree is below its maximum), and for an empty rest at degree 0."""
    ops = cpu_backend._ops()
    params = random_gaussians(40 + degree, 203, dtype, log_scale_sd=1.0)
    for rest_len in sorted({(degree + 1) ** 2 - 1, 15}):
        for width in (1, 8):
            previous = ops.project_lane_width(width)
            try:
                joined, split = _split_and_joined(project_cpu, params, tilted_camera(), degree, rest_len)
            finally:
                ops.project_lane_width(previous)
            for a, b in zip(joined, split):
                assert torch.equal(torch.nan_to_num(a, nan=7.0), torch.nan_to_num(b, nan=7.0)), (rest_len, width)


def test_render_takes_sh_in_two_parts_on_every_backend(project_cpu):
    """render(sh=DC, sh_rest=rest) gives what render(sh=joined) gives: the compiled path bit for bit, the
    reference path (which joins them) too; each part gets its own gradient."""
    camera = tilted_camera(61, 43)
    means, quats, scales, opacities, sh = _render_params(22, 300)
    degree = 2
    for backend in ("cpu", "reference"):
        joined_out, joined_grads = _render_grads(backend, [means, quats, scales, opacities, sh[:, :9].contiguous()],
                                                 camera, degree=degree)
        leaves = [t.clone().requires_grad_(True) for t in (means, quats, scales, opacities, sh[:, :1].contiguous(),
                                                           sh[:, 1:].contiguous())]
        out = render(*leaves[:5], camera=camera, sh_degree=degree, background=torch.tensor([0.2, 0.4, 0.6]),
                     backend=backend, sh_rest=leaves[5])
        g = torch.Generator().manual_seed(7)
        loss = ((out.color * torch.rand(out.color.shape, generator=g)).sum() + 0.05 * out.depth.sum()
                + (out.alpha * torch.rand(out.alpha.shape, generator=g)).sum())
        loss.backward()
        for field in ("color", "depth", "alpha"):
            assert torch.equal(getattr(out, field), getattr(joined_out, field)), (backend, field)
        sh_grad = torch.cat([leaves[4].grad, leaves[5].grad[:, :8]], dim=1)
        for a, b in zip([t.grad for t in leaves[:4]] + [sh_grad, out.means2d.grad], joined_grads):
            assert torch.equal(a, b), backend
        assert torch.all(leaves[5].grad[:, 8:] == 0)
    with pytest.raises(GsgsError, match="sh_rest"):
        render(means, quats, scales, opacities, sh[:, :1], camera, sh_degree=2, background=torch.zeros(3),
               sh_rest=sh[:, 1:4])
