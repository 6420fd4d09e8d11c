"""The pure-torch reference rasteriser against independent oracles: a literal per-pixel loop,
the analytic 2D Gaussian profile, numpy projection, and float64 gradcheck."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch

from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera
from gsgs_engine.render import api
from gsgs_engine.render import (covariance_3d, eval_sh, project_gaussians, quat_to_rotmat, rasterize_reference,
                                render, rgb_to_sh0, sh0_to_rgb)


@pytest.fixture(autouse=True)
def _single_thread():
    # These tensors are tiny: OpenMP threads only add synchronisation, which costs seconds
    # per gradcheck on a loaded 2-core machine.
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def make_camera(width=64, height=48, fx=60.0, fy=60.0, cx=None, cy=None, z=4.0) -> Camera:
    return Camera(R=np.eye(3), t=np.array([0.0, 0.0, z]), fx=fx, fy=fy,
                  cx=width / 2 if cx is None else cx, cy=height / 2 if cy is None else cy, width=width, height=height)


def loop_oracle(means2d, conics, colors, opacities, depths, radii, width, height, background):
    """The rasterisation semantics written as the literal per-pixel loop (numpy float64)."""
    m, con, col = (np.asarray(x, dtype=np.float64) for x in (means2d, conics, colors))
    op, dep, rad = np.asarray(opacities, np.float64), np.asarray(depths, np.float64), np.asarray(radii)
    bg = np.asarray(background, np.float64)
    gx, gy = math.ceil(width / 16), math.ceil(height / 16)
    image = np.zeros((height, width, 3))
    depth = np.zeros((height, width))
    alpha_img = np.zeros((height, width))
    ranges = []
    for i in range(len(op)):
        r = int(rad[i])
        if r <= 0:
            ranges.append(None)
            continue
        ranges.append((max(math.floor((m[i, 0] - r) / 16), 0), min(math.floor((m[i, 0] + r) / 16), gx - 1),
                       max(math.floor((m[i, 1] - r) / 16), 0), min(math.floor((m[i, 1] + r) / 16), gy - 1)))
    for y in range(height):
        for x in range(width):
            tx, ty = x // 16, y // 16
            ids = [i for i, rg in enumerate(ranges)
                   if rg is not None and rg[0] <= tx <= rg[1] and rg[2] <= ty <= rg[3]]
            ids.sort(key=lambda i: (dep[i], i))
            T, c, d = 1.0, np.zeros(3), 0.0
            for i in ids:
                dx, dy = m[i, 0] - (x + 0.5), m[i, 1] - (y + 0.5)
                power = -0.5 * (con[i, 0] * dx * dx + con[i, 2] * dy * dy) - con[i, 1] * dx * dy
                if power > 0:
                    continue
                a = min(0.99, op[i] * math.exp(power))
                if a < 1 / 255:
                    continue
                test_T = T * (1 - a)
                if test_T < 1e-4:
                    break
                c += col[i] * a * T
                d += dep[i] * a * T
                T = test_T
            image[y, x] = c + T * bg
            depth[y, x] = d
            alpha_img[y, x] = 1 - T
    return image, depth, alpha_img


def random_scene(n, seed, dtype=torch.float64, opacity_range=(0.05, 0.99), scale_range=(0.02, 0.3)):
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=g, dtype=dtype) * 2 - 1) * torch.tensor([1.6, 1.2, 1.0], dtype=dtype)
    quats = torch.randn(n, 4, generator=g, dtype=dtype)
    lo, hi = scale_range
    scales = torch.rand(n, 3, generator=g, dtype=dtype) * (hi - lo) + lo
    opacities = torch.rand(n, generator=g, dtype=dtype) * (opacity_range[1] - opacity_range[0]) + opacity_range[0]
    sh = torch.randn(n, 4, 3, generator=g, dtype=dtype) * 0.4
    return means, quats, scales, opacities, sh


@pytest.mark.parametrize("seed,n,size", [(0, 40, (37, 21)), (1, 120, (50, 40)), (2, 1, (16, 16))])
def test_reference_matches_literal_loop(seed, n, size):
    width, height = size
    cam = make_camera(width, height, fx=30.0, fy=30.0, cx=width / 2 + 1.3, cy=height / 2 - 0.7)
    means, quats, scales, opacities, sh = random_scene(n, seed)
    p = project_gaussians(means, quats, scales, cam, sh=sh, sh_degree=1)
    bg = torch.tensor([0.2, 0.5, 0.9], dtype=torch.float64)
    color, depth, alpha = rasterize_reference(p.means2d, p.conics, p.colors, opacities, p.depths, p.radii,
                                              width, height, bg)
    want_c, want_d, want_a = loop_oracle(p.means2d, p.conics, p.colors, opacities, p.depths, p.radii, width, height, bg)
    assert color.shape == (height, width, 3) and depth.shape == (height, width) and alpha.shape == (height, width)
    np.testing.assert_allclose(color.numpy(), want_c, atol=1e-10)
    np.testing.assert_allclose(depth.numpy(), want_d, atol=1e-10)
    np.testing.assert_allclose(alpha.numpy(), want_a, atol=1e-10)


def test_early_termination_and_chunking_agree_with_loop():
    # Thick stacks of nearly opaque Gaussians drive T below 1e-4, so the early stop matters;
    # tiny chunks force several Gaussian blocks per tile and the stop must carry across them.
    width, height = 40, 24
    cam = make_camera(width, height, fx=40.0, fy=40.0)
    means, quats, scales, opacities, sh = random_scene(60, 7, opacity_range=(0.8, 0.99), scale_range=(0.3, 0.8))
    p = project_gaussians(means, quats, scales, cam, sh=sh, sh_degree=1)
    bg = torch.tensor([1.0, 1.0, 1.0], dtype=torch.float64)
    want = loop_oracle(p.means2d, p.conics, p.colors, opacities, p.depths, p.radii, width, height, bg)
    assert (1 - want[2]).min() < 1e-3  # the stop rule is exercised (alpha capped at 1 - T >= 1e-4)
    for max_elements in (256, 256 * 5, 1 << 19):
        got = rasterize_reference(p.means2d, p.conics, p.colors, opacities, p.depths, p.radii, width, height, bg,
                                  max_elements=max_elements)
        for g, w in zip(got, want):
            np.testing.assert_allclose(g.numpy(), w, atol=1e-10)


def test_single_isotropic_gaussian_matches_analytic_profile():
    # Facing the camera on the optical axis: J = diag(fx/z, fy/z), so sigma_px^2 = (fx s / z)^2 + 0.3.
    width, height, fx, z, opacity = 64, 64, 80.0, 5.0, 0.8
    sigma_px = 4.0
    s = math.sqrt(sigma_px ** 2 - 0.3) * z / fx
    cam = make_camera(width, height, fx=fx, fy=fx, cx=32.5, cy=32.5, z=z)  # mean lands on pixel (32, 32)'s centre
    color_rgb = torch.tensor([0.9, 0.2, 0.4])
    out = render(torch.zeros(1, 3), torch.tensor([[1.0, 0, 0, 0]]), torch.full((1, 3), s), torch.tensor([opacity]),
                 rgb_to_sh0(color_rgb).reshape(1, 1, 3), cam, 0, torch.zeros(3), backend="reference")
    a = out.alpha
    assert a[32, 32].item() == pytest.approx(opacity, rel=1e-5)
    assert a[32, 36].item() == pytest.approx(opacity * math.exp(-0.5), rel=1e-5)  # 1 sigma right
    assert a[28, 32].item() == pytest.approx(opacity * math.exp(-0.5), rel=1e-5)  # 1 sigma up
    assert a[35, 36].item() == pytest.approx(opacity * math.exp(-0.5 * 25 / 16), rel=1e-5)  # (4, 3) px away
    # whole profile within the radius, where alpha >= 1/255
    yy, xx = torch.meshgrid(torch.arange(64) + 0.5, torch.arange(64) + 0.5, indexing="ij")
    analytic = opacity * torch.exp(-0.5 * ((xx - 32.5) ** 2 + (yy - 32.5) ** 2) / sigma_px ** 2)
    r = int(out.radii[0])
    assert r in (12, 13)  # ceil(3 sigma) with 3 sigma = 12 exactly: float32 rounding may tip it up
    inside = ((xx - 32.5).abs() <= r - 1) & ((yy - 32.5).abs() <= r - 1) & (analytic >= 1 / 255)
    torch.testing.assert_close(a[inside], analytic[inside], rtol=1e-4, atol=1e-6)
    torch.testing.assert_close(out.color, color_rgb * a[..., None], rtol=1e-4, atol=1e-6)
    torch.testing.assert_close(out.depth, z * a, rtol=1e-5, atol=1e-6)


def test_projection_matches_numpy_camera_and_eq2():
    cam = make_camera(80, 60, fx=70.0, fy=65.0, cx=37.0, cy=33.0)
    cam = cam.with_pose(cam.R @ np.array([[0.96, -0.28, 0], [0.28, 0.96, 0], [0, 0, 1.0]]), np.array([0.1, -0.2, 4.0]))
    means, quats, scales, _, _ = random_scene(30, 3)
    p = project_gaussians(means, quats, scales, cam)
    uv, z = cam.project(means.numpy())
    np.testing.assert_allclose(p.means2d.numpy(), uv, atol=1e-9)
    np.testing.assert_allclose(p.depths.numpy(), z, atol=1e-12)
    R = quat_to_rotmat(quats)
    torch.testing.assert_close(R @ R.transpose(1, 2), torch.eye(3, dtype=torch.float64).expand(30, 3, 3))
    assert torch.allclose(torch.linalg.det(R), torch.ones(30, dtype=torch.float64))
    want = R @ torch.diag_embed(scales ** 2) @ R.transpose(1, 2)
    torch.testing.assert_close(covariance_3d(quats, scales), want)
    # conic is the inverse of the dilated 2D covariance
    conic = p.conics[0]
    inv = torch.tensor([[conic[0], conic[1]], [conic[1], conic[2]]])
    cov2d = torch.linalg.inv(inv)
    lam = torch.linalg.eigvalsh(cov2d).max()
    assert int(p.radii[0]) == math.ceil(3 * math.sqrt(lam))


def test_sh_round_trip_and_degree_one_direction():
    rgb = torch.tensor([[0.1, 0.5, 0.9]])
    torch.testing.assert_close(sh0_to_rgb(rgb_to_sh0(rgb)), rgb)
    sh = torch.zeros(1, 4, 3)
    sh[0, 3] = 1.0  # the x-linear basis function, -C1 * x in 3DGS's sign convention
    x_dir = eval_sh(1, sh, torch.tensor([[1.0, 0.0, 0.0]]))
    torch.testing.assert_close(x_dir, torch.full((1, 3), -0.4886025119029199))
    torch.testing.assert_close(eval_sh(1, sh, torch.tensor([[0.0, 1.0, 0.0]])), torch.zeros(1, 3))
    with pytest.raises(ValueError):
        eval_sh(3, sh, torch.tensor([[1.0, 0.0, 0.0]]))


def _tiny_scene():
    """Three Gaussians on an 8x6 image, away from every clamp (alpha in (1/255, 0.99), T >> 1e-4)."""
    means = torch.tensor([[0.05, -0.02, 0.1], [-0.1, 0.08, 0.3], [0.12, 0.1, -0.2]], dtype=torch.float64)
    quats = torch.tensor([[0.9, 0.1, -0.2, 0.3], [0.7, -0.3, 0.2, 0.1], [1.0, 0.2, 0.1, -0.1]], dtype=torch.float64)
    scales = torch.tensor([[1.0, 0.8, 0.9], [0.85, 1.1, 1.0], [0.95, 1.0, 0.8]], dtype=torch.float64)
    opacities = torch.tensor([0.55, 0.4, 0.6], dtype=torch.float64)
    sh = torch.tensor([[[0.3, -0.2, 0.1]], [[-0.1, 0.2, 0.3]], [[0.2, 0.1, -0.3]]], dtype=torch.float64)
    sh = torch.cat([sh, 0.05 * torch.ones(3, 3, 3, dtype=torch.float64)], dim=1)
    cam = make_camera(8, 6, fx=10.0, fy=10.0, cx=4.2, cy=2.9, z=3.0)
    return cam, [means, quats, scales, opacities, sh]


@pytest.mark.parametrize("fast_mode", [True, pytest.param(False, marks=pytest.mark.slow)])
def test_gradcheck_full_pipeline_float64(fast_mode):
    # fast_mode checks random Jacobian-vector products (seconds); the full Jacobian takes ~20 s.
    cam, inputs = _tiny_scene()
    inputs = [x.clone().requires_grad_() for x in inputs]
    bg = torch.tensor([0.3, 0.6, 0.1], dtype=torch.float64, requires_grad=True)

    def f(means, quats, scales, opacities, sh, background):
        out = render(means, quats, scales, opacities, sh, cam, 1, background, backend="reference")
        return out.color, out.depth, out.alpha

    with torch.no_grad():
        color, _, alpha = f(*inputs, bg)
        assert alpha.min() > 0.2 and alpha.max() < 0.95 and color.min() > 0  # away from the kinks
    assert torch.autograd.gradcheck(f, (*inputs, bg), eps=1e-6, atol=1e-6, rtol=1e-4, fast_mode=fast_mode)


def test_gradcheck_rasterizer_inputs_float64():
    cam, (means, quats, scales, opacities, sh) = _tiny_scene()
    p = project_gaussians(means, quats, scales, cam, sh=sh, sh_degree=1)
    args = [p.means2d.detach(), p.conics.detach(), p.colors.detach(), opacities, p.depths.detach()]
    args = [a.clone().requires_grad_() for a in args]
    bg = torch.tensor([0.3, 0.6, 0.1], dtype=torch.float64, requires_grad=True)

    def f(m2d, conics, colors, ops, depths, background):
        return rasterize_reference(m2d, conics, colors, ops, depths, p.radii, 8, 6, background)

    assert torch.autograd.gradcheck(f, (*args, bg), eps=1e-6, atol=1e-6, rtol=1e-4)


def test_means2d_grad_is_screen_space_gradient():
    cam, inputs = _tiny_scene()
    means = inputs[0].clone().requires_grad_()
    out = render(means, *inputs[1:], cam, 1, torch.ones(3, dtype=torch.float64), backend="reference")
    out.color.sum().backward()
    g = out.means2d.grad
    assert g is not None and g.shape == (3, 2) and torch.isfinite(g).all() and g.abs().sum() > 0
    # chain rule: d/dmeans = d/dmeans2d * dmeans2d/dmeans (+ the covariance and colour paths), so
    # the screen-space gradient must reproduce a pure-screen-space perturbation.
    p = project_gaussians(means.detach(), *inputs[1:3], cam, sh=inputs[4], sh_degree=1)
    m2d = p.means2d.clone().requires_grad_()
    c, _, _ = rasterize_reference(m2d, p.conics, p.colors, inputs[3], p.depths, p.radii, 8, 6,
                                  torch.ones(3, dtype=torch.float64))
    c.sum().backward()
    torch.testing.assert_close(g, m2d.grad)


def test_auto_backend_warns_once_when_cpu_kernel_missing(monkeypatch):
    monkeypatch.setattr(api, "_cpu_module", lambda: (None, "no compiler found (test)"))
    monkeypatch.setattr(api, "_warned_cpu_fallback", False)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert api.select_backend("auto", torch.device("cpu")) == "reference"
        assert api.select_backend("auto", torch.device("cpu")) == "reference"
    msgs = [str(w.message) for w in caught if "compiled CPU rasteriser unavailable" in str(w.message)]
    assert len(msgs) == 1 and "no compiler found (test)" in msgs[0] and "gsgs build-ext" in msgs[0]
    with pytest.raises(GsgsError, match="build-ext"):
        api.select_backend("cpu", torch.device("cpu"))


def test_bad_backend_and_shapes_raise_clear_errors():
    cam, (means, quats, scales, opacities, sh) = _tiny_scene()
    with pytest.raises(GsgsError, match="unknown rasteriser backend"):
        render(means, quats, scales, opacities, sh, cam, 1, torch.ones(3), backend="vulkan")
    with pytest.raises(GsgsError, match=r"quats must be \[N, 4\]"):
        render(means, quats[:, :3], scales, opacities, sh, cam, 1, torch.ones(3))
    with pytest.raises(GsgsError, match="sh must be"):
        render(means, quats, scales, opacities, sh[:, :1], cam, 1, torch.ones(3))
    if not api.cuda_status()[0]:
        with pytest.raises(GsgsError, match="'cuda' unavailable"):
            render(means, quats, scales, opacities, sh, cam, 1, torch.ones(3), backend="cuda")


def test_gsplat_camera_conversion_projects_like_our_camera():
    from gsgs_engine.render.cuda_backend import camera_to_gsplat
    cam = make_camera(80, 60, fx=70.0, fy=65.0, cx=37.0, cy=33.0).with_pose(
        np.array([[0.96, -0.28, 0], [0.28, 0.96, 0], [0, 0, 1.0]]), np.array([0.1, -0.2, 4.0]))
    viewmat, K = camera_to_gsplat(cam, "cpu", torch.float64)
    pts = torch.tensor([[0.3, -0.4, 0.5], [-1.0, 0.2, 1.0]], dtype=torch.float64)
    p_cam = pts @ viewmat[0, :3, :3].T + viewmat[0, :3, 3]
    uvw = p_cam @ K[0].T
    uv, z = cam.project(pts.numpy())
    np.testing.assert_allclose((uvw[:, :2] / uvw[:, 2:]).numpy(), uv, atol=1e-9)
    np.testing.assert_allclose(p_cam[:, 2].numpy(), z, atol=1e-12)


@pytest.mark.parametrize("backend", ["cpu"])
def test_backend_matches_reference(backend):
    ok, reason = api.available_backends()[backend]
    if not ok:
        pytest.skip(f"backend {backend!r} unavailable: {reason}")
    cam = make_camera(70, 45, fx=50.0, fy=50.0, cx=33.0, cy=24.0)
    means, quats, scales, opacities, sh = random_scene(300, 11, dtype=torch.float32)
    results = {}
    for name in ("reference", backend):
        leaves = [x.clone().requires_grad_() for x in (means, quats, scales, opacities, sh)]
        out = render(*leaves, cam, 1, torch.tensor([0.1, 0.2, 0.3]), backend=name)
        ((out.color * torch.linspace(0, 1, 3)).sum() + 0.1 * out.depth.sum() + out.alpha.sum()).backward()
        results[name] = (out, [x.grad for x in leaves])
    ref, got = results["reference"], results[backend]
    for field in ("color", "depth", "alpha"):
        torch.testing.assert_close(getattr(got[0], field), getattr(ref[0], field), atol=1e-4, rtol=1e-4)
    for g, r in zip(got[1], ref[1]):
        torch.testing.assert_close(g, r, atol=1e-3, rtol=1e-3)


def test_bench_cell_measures_a_row_and_tabulates():
    from gsgs_engine.bench.rasterizer import markdown_table, run_cell
    row = run_cell("reference", 50, 32, repeats=2, budget_s=60.0, seed=0, threads=None)
    assert {"backend", "gaussians", "width", "height", "forward_ms", "forward_backward_ms", "peak_mb"} <= set(row)
    assert row["gaussians"] == 50 and row["width"] == row["height"] == 32
    assert 0 < row["forward_ms"] and 0 < row["forward_backward_ms"] and row["peak_mb"] >= 0
    skipped = run_cell("reference", 50, 32, repeats=2, budget_s=0.0, seed=0, threads=None)
    assert skipped["forward_ms"] is None and skipped["note"].startswith("skipped: over budget")
    table = markdown_table([{**row, "speedup_vs_reference": 1.0}, {**skipped, "speedup_vs_reference": None}])
    assert table.count("\n") == 3 and "| reference | 50 | 32x32 |" in table and "skipped: over budget" in table


def test_bench_thread_list_runs_each_count_and_reports_the_scaling(capsys):
    """`--threads 1,2` measures every cell at each count in one run (one subprocess per cell) and
    states the speed-up over the first count beside it."""
    import argparse

    from gsgs_engine.bench import rasterizer

    parser = argparse.ArgumentParser()
    rasterizer.add_arguments(parser)
    args = parser.parse_args(["--sizes", "200", "--resolutions", "32", "--repeats", "1", "--backends", "reference",
                              "--threads", "1,2"])
    assert rasterizer.run(args) == 0
    table = capsys.readouterr().out
    rows = [line for line in table.splitlines() if line.startswith("| reference |")]
    assert [r.split("|")[4].strip() for r in rows] == ["1", "2"]
    assert rows[0].split("|")[9].strip() == "1.00" and float(rows[1].split("|")[9]) > 0
