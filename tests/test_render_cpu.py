"""Parity of the compiled CPU rasteriser with the rasterisation semantics (oracle and reference)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from gsgs_engine import GsgsError
from gsgs_engine.render import cpu_backend

TILE = 16


@pytest.fixture(scope="module")
def cpu():
    if not cpu_backend.available():
        pytest.skip(f"compiled CPU rasteriser unavailable: {cpu_backend.unavailable_reason()}")
    return cpu_backend.rasterize_cpu


def random_scene(seed, n, width, height, equal_depth_groups=0, opaque_fraction=0.2, spread=6.0):
    """Projected Gaussians in the shapes rasterize() takes; float32."""
    g = torch.Generator().manual_seed(seed)
    u = lambda *shape: torch.rand(*shape, generator=g, dtype=torch.float64)  # noqa: E731
    means2d = torch.stack([u(n) * (width + 20) - 10, u(n) * (height + 20) - 10], -1)
    angle = u(n) * math.pi
    s1 = 0.5 + u(n) * spread
    s2 = 0.5 + u(n) * spread
    c, s = torch.cos(angle), torch.sin(angle)
    cov_a = c * c * s1 * s1 + s * s * s2 * s2 + 0.3
    cov_b = c * s * (s1 * s1 - s2 * s2)
    cov_c = s * s * s1 * s1 + c * c * s2 * s2 + 0.3
    det = cov_a * cov_c - cov_b * cov_b
    conics = torch.stack([cov_c / det, -cov_b / det, cov_a / det], -1)
    mid = 0.5 * (cov_a + cov_c)
    lam = mid + torch.sqrt(torch.clamp(mid * mid - det, min=0.1))
    radii = torch.ceil(3.0 * torch.sqrt(lam)).to(torch.int32)
    opacities = 0.05 + 0.9 * u(n)
    opaque = u(n) < opaque_fraction
    opacities[opaque] = 0.995  # alpha clamps at 0.99 near the centre, pixels reach the T < 1e-4 stop
    colors = u(n, 3) * 1.2
    depths = 1.0 + 9.0 * u(n)
    if equal_depth_groups:
        group = (u(n) * equal_depth_groups).long()
        depths = 1.0 + group.to(torch.float64)  # many exact ties: order falls back to the index
    radii[u(n) < 0.05] = 0  # culled
    background = torch.tensor([0.2, 0.5, 0.9], dtype=torch.float64)
    f = lambda t: t.to(torch.float32).contiguous()  # noqa: E731
    return dict(means2d=f(means2d), conics=f(conics), colors=f(colors), opacities=f(opacities),
                depths=f(depths), radii=radii, width=width, height=height, background=f(background))


def oracle(means2d, conics, colors, opacities, depths, radii, width, height, background, centres=None):
    """Direct transcription of the semantics in float64 torch (autograd): per Gaussian in
    (depth, index) order, every pixel of the tiles it touches, front to back. `centres` [N, H, W, 2] (float64):
    every pixel's own copy of every centre (binning still reads means2d), so its gradient is each pixel's own."""
    n = means2d.shape[0]
    dt = torch.float64
    ys, xs = torch.meshgrid(torch.arange(height, dtype=dt) + 0.5, torch.arange(width, dtype=dt) + 0.5, indexing="ij")
    tile_x = torch.div(torch.arange(width), TILE, rounding_mode="floor")[None, :].expand(height, width)
    tile_y = torch.div(torch.arange(height), TILE, rounding_mode="floor")[:, None].expand(height, width)
    T = torch.ones(height, width, dtype=dt)
    color = torch.zeros(height, width, 3, dtype=dt)
    depth = torch.zeros(height, width, dtype=dt)
    active = torch.ones(height, width, dtype=torch.bool)
    order = sorted(range(n), key=lambda i: (float(depths[i].detach()), i))
    for i in order:
        r = int(radii[i])
        if r <= 0:
            continue
        mx, my = float(means2d[i, 0].detach()), float(means2d[i, 1].detach())  # binned in double, as the reference
        tx0, tx1 = math.floor((mx - r) / 16), math.floor((mx + r) / 16)
        ty0, ty1 = math.floor((my - r) / 16), math.floor((my + r) / 16)
        in_tiles = (tile_x >= tx0) & (tile_x <= tx1) & (tile_y >= ty0) & (tile_y <= ty1)
        centre = means2d[i].to(dt) if centres is None else centres[i]
        dx = centre[..., 0] - xs
        dy = centre[..., 1] - ys
        a, b, c = conics[i, 0].to(dt), conics[i, 1].to(dt), conics[i, 2].to(dt)
        power = -0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy
        alpha = torch.clamp(opacities[i].to(dt) * torch.exp(power), max=0.99)
        valid = in_tiles & active & (power <= 0) & (alpha >= 1.0 / 255.0)
        test_T = T * (1 - alpha)
        stop = valid & (test_T < 1e-4)
        add = valid & ~stop
        w = torch.where(add, alpha * T, torch.zeros((), dtype=dt))
        color = color + w[..., None] * colors[i].to(dt)
        depth = depth + w * depths[i].to(dt)
        T = torch.where(add, test_T, T)
        active = active & ~stop
    color = color + T[..., None] * background.to(dt)
    return color, depth, 1 - T


def reference_or_skip():
    try:
        from gsgs_engine.render.reference import rasterize_reference
    except ImportError as exc:
        pytest.skip(f"gsgs_engine.render.reference is not importable yet: {exc}")
    return rasterize_reference


SCENES = [
    dict(seed=0, n=40, width=16, height=12),  # the 16x12 image: one partial tile
    dict(seed=1, n=60, width=37, height=23),  # non-square, partial tiles on both axes
    dict(seed=2, n=80, width=48, height=33, equal_depth_groups=3),  # many exact depth ties
    dict(seed=3, n=120, width=40, height=40, opaque_fraction=0.6, spread=10.0),  # heavy overlap, T stops
    dict(seed=4, n=30, width=21, height=50, spread=2.0),  # tall, small Gaussians, many off-image
    # long rotated ellipses over many tiles: binning culls their rectangles row by row to the tiles they reach
    dict(seed=5, n=40, width=96, height=80, spread=25.0),
]


def _inputs(scene, grad=True):
    x = {k: (v.clone().requires_grad_(grad) if isinstance(v, torch.Tensor) and v.is_floating_point() else v)
         for k, v in scene.items()}
    return x


def _grads(fn, scene, seed):
    x = _inputs(scene)
    color, depth, alpha = fn(**x)
    g = torch.Generator().manual_seed(100 + seed)
    wc = torch.randn(color.shape, generator=g, dtype=torch.float64)
    wd = torch.randn(depth.shape, generator=g, dtype=torch.float64) * 0.1
    wa = torch.randn(alpha.shape, generator=g, dtype=torch.float64)
    loss = (color.double() * wc).sum() + (depth.double() * wd).sum() + (alpha.double() * wa).sum()
    loss.backward()
    names = ["means2d", "conics", "colors", "opacities", "depths", "background"]
    return (color.detach(), depth.detach(), alpha.detach()), {k: x[k].grad for k in names}


def _rel_err(a, b):
    a, b = a.double(), b.double()
    return float((a - b).norm() / b.norm().clamp_min(1e-12))


def _assert_parity(out, ref_out, grads, ref_grads, label):
    for name, a, b in zip(("color", "depth", "alpha"), out, ref_out):
        err = float((a.double() - b.double()).abs().max())
        # depth is sum z*alpha*T with z up to 10: compare it relative to its scale
        tol = 1e-4 * (10.0 if name == "depth" else 1.0)
        assert err < tol, f"{label}: forward {name} differs by {err:.3g}"
    for name, g in grads.items():
        rg = ref_grads[name]
        assert g is not None and rg is not None, f"{label}: no gradient for {name}"
        assert torch.isfinite(g).all(), f"{label}: non-finite gradient for {name}"
        err = _rel_err(g, rg)
        assert err < 1e-3, f"{label}: gradient of {name} differs (relative {err:.3g})"


@pytest.mark.parametrize("params", SCENES, ids=lambda p: f"seed{p['seed']}-{p['width']}x{p['height']}")
def test_matches_oracle(cpu, params):
    scene = random_scene(**params)
    out, grads = _grads(cpu, scene, params["seed"])
    ref_out, ref_grads = _grads(oracle, scene, params["seed"])
    _assert_parity(out, ref_out, grads, ref_grads, "oracle")


@pytest.mark.parametrize("params", SCENES, ids=lambda p: f"seed{p['seed']}-{p['width']}x{p['height']}")
def test_matches_reference(cpu, params):
    rasterize_reference = reference_or_skip()
    scene = random_scene(**params)
    out, grads = _grads(cpu, scene, params["seed"])
    ref_out, ref_grads = _grads(rasterize_reference, scene, params["seed"])
    _assert_parity(out, ref_out, grads, ref_grads, "reference")


@pytest.mark.slow
def test_larger_scene_matches_reference(cpu):
    rasterize_reference = reference_or_skip()
    scene = random_scene(seed=7, n=600, width=130, height=97, equal_depth_groups=20, spread=12.0)
    out, grads = _grads(cpu, scene, 7)
    ref_out, ref_grads = _grads(rasterize_reference, scene, 7)
    _assert_parity(out, ref_out, grads, ref_grads, "reference 130x97")


def _camera_scene(seed, n, width, height):
    from gsgs_engine.cameras import Camera

    g = torch.Generator().manual_seed(seed)
    camera = Camera(R=np.eye(3), t=np.array([0.1, -0.05, 0.0]), fx=0.9 * width, fy=0.95 * width,
                    cx=width / 2 + 1.7, cy=height / 2 - 2.3, width=width, height=height)
    means = torch.stack([torch.rand(n, generator=g) * 2.4 - 1.2, torch.rand(n, generator=g) * 1.8 - 0.9,
                         2.0 + torch.rand(n, generator=g) * 3.0], -1)
    means[: n // 8, 2] = 3.0  # equal depths
    quats = torch.randn(n, 4, generator=g)
    scales = 0.01 + 0.08 * torch.rand(n, 3, generator=g)
    opacities = 0.1 + 0.89 * torch.rand(n, generator=g)
    sh = torch.randn(n, 16, 3, generator=g) * 0.3
    return camera, [means, quats, scales, opacities, sh]


def test_render_cpu_matches_reference_through_projection(cpu):
    from gsgs_engine.render.api import render

    camera, params = _camera_scene(seed=12, n=150, width=53, height=41)
    background = torch.tensor([0.3, 0.3, 0.3])
    results = {}
    for backend in ("cpu", "reference"):
        leaves = [p.clone().requires_grad_(True) for p in params]
        out = render(*leaves, camera=camera, sh_degree=3, background=background, backend=backend)
        assert out.backend == backend
        g = torch.Generator().manual_seed(3)
        loss = ((out.color * torch.rand(out.color.shape, generator=g)).sum() + 0.05 * out.depth.sum()
                + (out.alpha * torch.rand(out.alpha.shape, generator=g)).sum())
        loss.backward()
        results[backend] = (out, [p.grad for p in leaves])
    (out_c, grads_c), (out_r, grads_r) = results["cpu"], results["reference"]
    assert int(out_c.visible.sum()) > 100
    for field, tol in (("color", 1e-4), ("depth", 1e-3), ("alpha", 1e-4)):
        diff = (getattr(out_c, field) - getattr(out_r, field)).detach().abs().max()
        assert float(diff) < tol, field
    assert _rel_err(out_c.means2d.grad, out_r.means2d.grad) < 1e-3  # what densification reads
    for name, gc, gr in zip(("means", "quats", "scales", "opacities", "sh"), grads_c, grads_r):
        assert _rel_err(gc, gr) < 1e-3, name


def test_scenes_exercise_the_edge_cases(cpu):
    # The parity scenes are only meaningful if they hit the early stop, the ties and partial tiles.
    scene = random_scene(**SCENES[3])
    _, _, alpha = cpu(**scene)
    assert float(alpha.max()) > 1 - 1e-3, "no pixel reached the T < 1e-4 stop"
    assert len(torch.unique(random_scene(**SCENES[2])["depths"])) <= 3
    assert SCENES[1]["width"] % TILE and SCENES[1]["height"] % TILE


def test_tile_binning_at_a_float32_rounding_boundary(cpu):
    # m + r = 32 - 2^-20 rounds up to 32.0 in float32 but not in exact arithmetic: the Gaussian must not
    # reach the third tile column (x >= 32), exactly as the reference bins.
    mx = 16.0 - 2.0 ** -20
    scene = dict(means2d=torch.tensor([[mx, 8.0]]), conics=torch.tensor([[0.02, 0.0, 0.02]]),
                 colors=torch.tensor([[1.0, 0.0, 0.0]]), opacities=torch.tensor([0.99]), depths=torch.tensor([1.0]),
                 radii=torch.tensor([16], dtype=torch.int32), width=48, height=16, background=torch.zeros(3))
    assert float(scene["means2d"][0, 0]) + 16 < 32 and float(scene["means2d"][0, 0] + 16) == 32.0
    color, _, alpha = cpu(**scene)
    assert float(alpha[:, 32:].max()) == 0.0
    assert float(alpha[8, 31]) > 0  # close to the boundary the Gaussian is still visible
    ref_color, _, _ = oracle(**scene)
    assert float((color.double() - ref_color).abs().max()) < 1e-5


def test_deterministic_across_thread_counts(cpu):
    scene = random_scene(seed=11, n=400, width=70, height=45, spread=9.0)
    before = torch.get_num_threads()
    results = []
    try:
        for threads in (1, 2):
            torch.set_num_threads(threads)
            results.append(_grads(cpu, scene, 11))
    finally:
        torch.set_num_threads(before)
    (out1, g1), (out2, g2) = results
    for a, b in zip(out1, out2):
        assert torch.equal(a, b)
    for k in g1:
        assert torch.equal(g1[k], g2[k]), f"gradient of {k} depends on the thread count"


def test_culled_and_out_of_image_gaussians_get_no_gradient(cpu):
    scene = random_scene(seed=5, n=50, width=32, height=32)
    scene["radii"][:5] = 0
    scene["means2d"][5:8] = torch.tensor([[-200.0, 10.0], [10.0, 500.0], [1e6, 1e6]])
    _, grads = _grads(cpu, scene, 5)
    for k in ("means2d", "conics", "colors", "opacities", "depths"):
        assert torch.all(grads[k][:8] == 0), k
        assert grads[k][8:].abs().sum() > 0, k


def test_empty_and_fully_transparent(cpu):
    bg = torch.tensor([0.1, 0.2, 0.3], requires_grad=True)
    z = torch.zeros
    color, depth, alpha = cpu(z(0, 2), z(0, 3), z(0, 3), z(0), z(0), z(0, dtype=torch.int32), 19, 7, bg)
    assert color.shape == (7, 19, 3) and depth.shape == (7, 19) and alpha.shape == (7, 19)
    assert torch.allclose(color, bg.detach().expand(7, 19, 3)) and torch.all(depth == 0) and torch.all(alpha == 0)
    color.sum().backward()
    assert torch.allclose(bg.grad, torch.full((3,), 7.0 * 19.0))


def test_nan_gaussian_is_ignored_not_crashing(cpu):
    scene = random_scene(seed=6, n=20, width=32, height=32)
    clean = cpu(**scene)
    scene["means2d"][0] = float("nan")
    scene["radii"][0] = 3
    dirty = cpu(**scene)
    assert all(torch.isfinite(t).all() for t in dirty)
    scene["radii"][0] = 0
    assert all(torch.equal(a, b) for a, b in zip(cpu(**scene), dirty))
    assert clean[0].shape == dirty[0].shape


def test_bad_inputs_raise_clear_errors(cpu):
    scene = random_scene(seed=8, n=10, width=16, height=16)
    as64 = {k: (v.double() if isinstance(v, torch.Tensor) and v.is_floating_point() else v) for k, v in scene.items()}
    with pytest.raises(GsgsError, match="float32 only"):
        cpu(**as64)
    bad = dict(scene, conics=scene["conics"][:, :2])
    with pytest.raises(GsgsError, match="conics has shape"):
        cpu(**bad)
    with pytest.raises(GsgsError, match="image size"):
        cpu(**dict(scene, width=0))


def test_second_load_reuses_the_build(cpu):
    # available() succeeded, so the finished build is on disk and later processes only load it.
    assert cpu_backend.is_built()
    assert cpu_backend.unavailable_reason() is None


def test_build_error_summary_names_the_compiler_error():
    log = ("Error building extension 'gsgs_rasterize_cpu_x': [1/2] c++ -MMD -c rasterize_cpu.cpp -o rasterize_cpu.o\n"
           "FAILED: rasterize_cpu.o\n"
           "rasterize_cpu.cpp:12:3: error: 'foo' was not declared in this scope\n"
           "ninja: build stopped: subcommand failed.\n")
    summary = cpu_backend._summarise_build_error(RuntimeError(log))
    assert summary == "rasterize_cpu.cpp:12:3: error: 'foo' was not declared in this scope"
    assert cpu_backend._summarise_build_error(RuntimeError("ninja is not installed")) == "ninja is not installed"


def test_build_dir_is_keyed_and_overridable(monkeypatch, tmp_path):
    monkeypatch.setenv("GSGS_BUILD_DIR", str(tmp_path))
    d = cpu_backend.build_dir()
    assert d.parent == tmp_path and len(d.name) == 16
    monkeypatch.delenv("GSGS_BUILD_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    assert cpu_backend.build_dir() == tmp_path / "cache" / "gsgs" / "torch_extensions" / d.name


def test_oracle_agrees_with_a_plain_pixel_loop():
    # Guards the oracle itself: a literal per-pixel loop (the semantics word for word) on a tiny image.
    scene = random_scene(seed=9, n=12, width=16, height=12, opaque_fraction=0.5)
    color, depth, alpha = oracle(**scene)
    m, cn, col = scene["means2d"].double(), scene["conics"].double(), scene["colors"].double()
    op, dp, rad, bg = scene["opacities"].double(), scene["depths"], scene["radii"], scene["background"].double()
    order = sorted(range(12), key=lambda i: (float(dp[i]), i))
    for y in range(12):
        for x in range(16):
            T, c, d = 1.0, np.zeros(3), 0.0
            for i in order:
                r = int(rad[i])
                if r <= 0:
                    continue
                tx = (math.floor((float(m[i, 0]) - r) / 16), math.floor((float(m[i, 0]) + r) / 16))
                ty = (math.floor((float(m[i, 1]) - r) / 16), math.floor((float(m[i, 1]) + r) / 16))
                if not (tx[0] <= x // 16 <= tx[1] and ty[0] <= y // 16 <= ty[1]):
                    continue
                dx, dy = float(m[i, 0]) - (x + 0.5), float(m[i, 1]) - (y + 0.5)
                power = -0.5 * (float(cn[i, 0]) * dx * dx + float(cn[i, 2]) * dy * dy) - float(cn[i, 1]) * dx * dy
                if power > 0:
                    continue
                a = min(0.99, float(op[i]) * math.exp(power))
                if a < 1 / 255:
                    continue
                if T * (1 - a) < 1e-4:
                    break
                c += col[i].numpy() * a * T
                d += float(dp[i]) * a * T
                T *= 1 - a
            c += T * bg.numpy()
            assert np.allclose(color[y, x].numpy(), c, atol=1e-9)
            assert abs(float(depth[y, x]) - d) < 1e-9 and abs(float(alpha[y, x]) - (1 - T)) < 1e-9


_VARIANT_SCRIPT = """
import sys, torch
sys.path[:0] = [sys.argv[2]]
from test_render_cpu import SCENES, _grads, random_scene
from gsgs_engine.render import cpu_backend
assert cpu_backend.available(), cpu_backend.unavailable_reason()
fn = cpu_backend.rasterize_cpu
out = {}
for params in SCENES + [dict(seed=9, n=300, width=64, height=48, spread=9.0, opaque_fraction=0.5)]:
    (color, depth, alpha), grads = _grads(fn, random_scene(**params), params["seed"])
    out[params["seed"]] = {"color": color, "depth": depth, "alpha": alpha, **grads}
torch.save(out, sys.argv[1])
"""


def test_every_tile_variant_renders_the_same(cpu, tmp_path):
    """The kernel's builds of its tile loops (AVX-512VL, AVX2 + FMA, AVX2, portable x86-64), each forced in its own
    process: the two without FMA are bit-identical (same operations lane for lane), the FMA ones within rounding.
    On a processor without AVX-512 its variant falls back to the FMA one (never chosen where it cannot run)."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    tests_dir = str(Path(__file__).resolve().parent)
    results = {}
    for variant in ("avx512", "fma", "avx2", "portable"):
        env = {**os.environ, "GSGS_TILE_VARIANT": variant}
        env.pop("GSGS_NO_FMA", None)
        path = tmp_path / f"{variant}.pt"
        proc = subprocess.run([sys.executable, "-c", _VARIANT_SCRIPT, str(path), tests_dir], env=env,
                              capture_output=True, text=True, timeout=600)
        assert proc.returncode == 0, proc.stderr[-2000:]
        results[variant] = torch.load(path)
    # the FMA build rounds differently somewhere: proof that each process ran the variant it was told to
    assert any(not torch.equal(results["fma"][seed][name], value) for seed, ref in results["avx2"].items()
               for name, value in ref.items())
    for seed, ref in results["portable"].items():
        for name, value in ref.items():
            assert torch.equal(results["avx2"][seed][name], value), f"seed {seed}: avx2 and portable differ in {name}"
            for variant in ("fma", "avx512"):
                fma = results[variant][seed][name]
                assert torch.isfinite(fma).all()
                err = float((fma.double() - value.double()).norm() / value.double().norm().clamp_min(1e-12))
                assert err < 1e-4, f"seed {seed}: the {variant} variant's {name} differs by {err:.3g} (relative)"
