"""AbsGS's densification statistic: the compiled rasteriser's per-pixel absolute screen-space gradients.

The oracle is test_render_cpu's float64 transcription of the compositing, with each Gaussian's centre given to every
pixel as its own leaf (its `centres`), so one backward yields every pixel's own dL_p/dmeans2d; their absolute values
summed over the pixels are what `means2d.absgrad` must hold.
"""

from __future__ import annotations

import pytest
import torch

from gsgs_engine import GsgsError
from gsgs_engine.render import cpu_backend
from test_render_cpu import oracle, random_scene

SCENES = [
    dict(seed=0, n=40, width=16, height=12),
    dict(seed=1, n=60, width=37, height=23),
    dict(seed=3, n=120, width=40, height=40, opaque_fraction=0.6, spread=10.0),  # T stops, heavy overlap
    dict(seed=5, n=40, width=96, height=80, spread=25.0),  # long ellipses over many tiles
]


@pytest.fixture(scope="module")
def cpu():
    if not cpu_backend.available():
        pytest.skip(f"compiled CPU rasteriser unavailable: {cpu_backend.unavailable_reason()}")
    return cpu_backend.rasterize_cpu


def _weights(shape_hw, seed):
    g = torch.Generator().manual_seed(100 + seed)
    h, w = shape_hw
    return (torch.randn(h, w, 3, generator=g, dtype=torch.float64),
            torch.randn(h, w, generator=g, dtype=torch.float64) * 0.1,
            torch.randn(h, w, generator=g, dtype=torch.float64))


def oracle_absgrad(scene, weights):
    """(sum_p |dL_p/dmeans2d| [N, 2], dL/dmeans2d [N, 2]) in float64, L = sum_p <weights, (colour, depth, alpha)>."""
    n, height, width = scene["means2d"].shape[0], scene["height"], scene["width"]
    own = scene["means2d"].to(torch.float64)[:, None, None, :].expand(n, height, width, 2).clone().requires_grad_(True)
    color, depth, alpha = oracle(**scene, centres=own)
    wc, wd, wa = weights
    ((color * wc).sum() + (depth * wd).sum() + (alpha * wa).sum()).backward()
    per_pixel = own.grad  # [N, H, W, 2]: each pixel's own gradient of every centre
    return per_pixel.abs().sum(dim=(1, 2)), per_pixel.sum(dim=(1, 2))


def _kernel(cpu, scene, weights, absgrad=True):
    means2d = scene["means2d"].clone().requires_grad_(True)
    rest = {k: v for k, v in scene.items() if k != "means2d"}
    color, depth, alpha = cpu(means2d, **rest, absgrad=absgrad)
    wc, wd, wa = weights
    ((color.double() * wc).sum() + (depth.double() * wd).sum() + (alpha.double() * wa).sum()).backward()
    return getattr(means2d, "absgrad", None), means2d.grad


def _rel(a, b):
    return float((a.double() - b.double()).norm() / b.double().norm().clamp_min(1e-12))


@pytest.mark.parametrize("params", SCENES, ids=lambda p: f"seed{p['seed']}_{p['width']}x{p['height']}")
def test_absgrad_matches_the_per_pixel_oracle(cpu, params):
    scene = random_scene(**params)
    weights = _weights((params["height"], params["width"]), params["seed"])
    want_abs, want_sum = oracle_absgrad(scene, weights)
    got_abs, got_sum = _kernel(cpu, scene, weights)
    assert got_abs is not None and got_abs.shape == (params["n"], 2) and got_abs.dtype == torch.float32
    assert _rel(got_sum, want_sum) < 1e-4  # the oracle is the compositing the kernel implements
    assert _rel(got_abs, want_abs) < 1e-4, f"absgrad off by {_rel(got_abs, want_abs):.3g} (relative)"
    # |sum| <= sum |.| per axis; the scenes have Gaussians whose pixels disagree, where it is strict
    assert bool((got_abs >= got_sum.abs() * (1 - 1e-5) - 1e-7).all())
    assert bool((want_abs > want_sum.abs() * 1.01).any())
    # culled Gaussians (radius 0) get 0
    assert bool((got_abs[scene["radii"] == 0] == 0).all())


def test_absgrad_leaves_the_gradients_bit_identical(cpu):
    params = SCENES[2]
    scene = random_scene(**params)
    weights = _weights((params["height"], params["width"]), params["seed"])
    grads = {}
    for absgrad in (False, True):
        x = {k: (v.clone().requires_grad_(True) if isinstance(v, torch.Tensor) and v.is_floating_point() else v)
             for k, v in scene.items()}
        color, depth, alpha = cpu(**x, absgrad=absgrad)
        wc, wd, wa = weights
        ((color.double() * wc).sum() + (depth.double() * wd).sum() + (alpha.double() * wa).sum()).backward()
        grads[absgrad] = {k: x[k].grad for k in ("means2d", "conics", "colors", "opacities", "depths")}
        assert hasattr(x["means2d"], "absgrad") == absgrad
    for k, g in grads[False].items():
        assert torch.equal(g, grads[True][k]), k


def test_absgrad_is_the_same_at_any_thread_count(cpu):
    scene = random_scene(seed=11, n=400, width=70, height=45, spread=9.0)
    weights = _weights((45, 70), 11)
    before = torch.get_num_threads()
    try:
        results = []
        for threads in (1, 2, 3):
            torch.set_num_threads(threads)
            results.append(_kernel(cpu, scene, weights)[0])
    finally:
        torch.set_num_threads(before)
    assert torch.equal(results[0], results[1]) and torch.equal(results[0], results[2])


def test_absgrad_with_a_nonfinite_gaussian_stays_finite(cpu):
    params = SCENES[1]
    scene = random_scene(**params)
    scene["means2d"][3] = float("nan")
    scene["conics"][5, 0] = float("inf")
    weights = _weights((params["height"], params["width"]), params["seed"])
    got_abs, _ = _kernel(cpu, scene, weights)
    assert bool(torch.isfinite(got_abs).all())


def test_render_with_absgrad_through_projection_and_on_the_reference_backend():
    from gsgs_engine.render import render
    from test_render_cpu import _camera_scene

    camera, params = _camera_scene(seed=12, n=150, width=53, height=41)
    if cpu_backend.available():
        x = [t.clone().requires_grad_(True) for t in params]
        out = render(*x, camera, sh_degree=3, background=(1.0, 1.0, 1.0), backend="cpu", absgrad=True)
        out.color.sum().backward()
        absgrad = out.means2d.absgrad
        assert absgrad.shape == (150, 2) and bool(torch.isfinite(absgrad).all())
        assert bool((absgrad[out.radii == 0] == 0).all()) and bool((absgrad[out.radii > 0] > 0).any())
        assert bool((absgrad >= out.means2d.grad.abs() * (1 - 1e-5) - 1e-7).all())
        with pytest.raises(GsgsError, match="contiguous"):
            scene = random_scene(**SCENES[0])
            scene["means2d"] = scene["means2d"].t().contiguous().t()  # same values, not contiguous
            cpu_backend.rasterize_cpu(**scene, absgrad=True)
    x = [t.clone().requires_grad_(True) for t in params]
    with pytest.raises(GsgsError, match="absgrad"):
        render(*x, camera, sh_degree=3, background=(1.0, 1.0, 1.0), backend="reference", absgrad=True)
