"""Depth distortion: the ray's depth spread from the real compositing, its gradient, training with it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera
from gsgs_engine.train.techniques.catalogue import make_techniques, parse_techniques
from gsgs_engine.train.techniques.distortion import DepthDistortion, composite_moments, ray_depth_spread
from test_trainer import make_trainer

BACKENDS = ["reference", "cpu"]


def _layers(depths, opacity=0.6):
    """One broad flat-ish Gaussian per depth in front of a camera at the origin looking down +z."""
    n = len(depths)
    return {"means": torch.tensor([[0.0, 0.0, float(z)] for z in depths]),
            "quats": torch.tensor([[1.0, 0.0, 0.0, 0.0]] * n),
            "scales": torch.tensor([[20.0, 20.0, 0.01]] * n),
            "opacities": torch.full((n,), opacity),
            "sh": torch.zeros(n, 1, 3)}


def _camera(size=24):
    return Camera(R=np.eye(3), t=np.zeros(3), fx=20.0, fy=20.0, cx=size / 2, cy=size / 2, width=size, height=size,
                  name="c")


@pytest.mark.parametrize("backend", BACKENDS)
def test_one_surface_has_no_spread_and_two_layers_have_their_variance(backend):
    cam = _camera()
    alpha, s1, s2 = composite_moments(_layers([4.0]), cam, 4.0, backend)
    centre = (12, 12)
    assert float(alpha[centre]) == pytest.approx(0.6, abs=1e-3)
    assert float(s1[centre] / alpha[centre]) == pytest.approx(1.0, rel=1e-3)  # s = z_ref / z
    assert float(ray_depth_spread(alpha, s1, s2)[centre]) == pytest.approx(0.0, abs=1e-5)
    # two layers: weights 0.6 (s = 1) and 0.4 * 0.6 = 0.24 (s = 0.5): the weighted variance of {1, 0.5}
    alpha, s1, s2 = composite_moments(_layers([4.0, 8.0]), cam, 4.0, backend)
    w = torch.tensor([0.6, 0.24])
    s = torch.tensor([1.0, 0.5])
    p = w / w.sum()
    expected = float((p * s * s).sum() - (p * s).sum() ** 2)
    assert float(ray_depth_spread(alpha, s1, s2)[centre]) == pytest.approx(expected, rel=1e-3)


@pytest.mark.parametrize("backend", BACKENDS)
def test_the_gradient_draws_the_layers_together_and_is_finite(backend):
    cam = _camera()
    layers = _layers([4.0, 6.0])
    layers["means"].requires_grad_(True)
    alpha, s1, s2 = composite_moments(layers, cam, 4.0, backend)
    ray_depth_spread(alpha, s1, s2).mean().backward()
    g = layers["means"].grad
    assert torch.isfinite(g).all()
    assert g[0, 2] < 0 < g[1, 2]  # descent moves the near layer back and the far one forward


def test_spread_is_finite_where_nothing_is_drawn_and_behind_the_camera():
    cam = _camera()
    layers = _layers([-3.0, 5.0])  # one Gaussian behind the camera
    layers["means"].requires_grad_(True)
    alpha, s1, s2 = composite_moments(layers, cam, 4.0, "reference")
    spread = ray_depth_spread(alpha, s1, s2)
    empty = ray_depth_spread(torch.zeros(3, 3), torch.zeros(3, 3), torch.zeros(3, 3))
    assert torch.isfinite(spread).all() and torch.equal(empty, torch.zeros(3, 3))
    spread.mean().backward()
    assert torch.isfinite(layers["means"].grad).all()


def test_options_are_checked():
    for bad in ("distortion:weight=-1", "distortion:scale=0", "distortion:every=0", "distortion:start_fraction=1"):
        with pytest.raises(GsgsError, match="distortion"):
            make_techniques(parse_techniques(bad))


@pytest.mark.slow  # tens of steps of the tiny scene
def test_training_with_distortion_stays_finite_and_resumes_to_the_bit(tmp_path):
    def run(folder, until=None, resume=False):
        trainer = make_trainer(tmp_path=folder, iters=20, densify=True, checkpoint_every=10, seed=3)
        trainer.setup(resume=resume)
        tech = trainer.add_technique(DepthDistortion(weight=1.0, start_fraction=0.1))
        trainer.train(until=until)
        return trainer, tech

    straight, tech = run(tmp_path / "a")
    assert tech.steps > 0 and tech.report()["z_ref"] > 0
    assert straight.model.all_finite() and straight.nan_steps_skipped == 0
    run(tmp_path / "b", until=10)
    resumed, tech_b = run(tmp_path / "b", resume=True)
    assert resumed.step == 20 and tech_b.report() == tech.report()
    for name, value in straight.model.params.items():
        assert torch.equal(value, resumed.model.params[name]), name
