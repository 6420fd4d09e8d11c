"""The textured background sphere (gsgs_engine.train.background_sphere): where a ray meets it, how it composites,
how it trains, resumes, is written beside the PLY and read back by `gsgs eval`, and how the effect plan names it."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera, look_at
from gsgs_engine.train.background_sphere import (BackgroundSphere, TEXTURE_FILE, check_width, ray_texture_coords,
                                                 sphere_through)
from tests.test_trainer import make_scene, make_trainer


def _camera(eye, target, size=9, fov_deg=60.0, up=(0.0, 0.0, 1.0)) -> Camera:
    R, t = look_at(np.asarray(eye, float), np.asarray(target, float), up)
    f = 0.5 * size / math.tan(math.radians(fov_deg) / 2)
    return Camera(R=R, t=t, fx=f, fy=f, cx=size / 2, cy=size / 2, width=size, height=size)


def _centre_pixel(grid: torch.Tensor) -> tuple[float, float]:
    h, w = grid.shape[1:3]
    return tuple(float(x) for x in grid[0, h // 2, w // 2])


def test_a_ray_meets_the_sphere_where_it_leaves_it():
    centre = np.array([1.0, -2.0, 0.5])
    # from the centre looking along +x: longitude 0, latitude 0
    lon, lat = _centre_pixel(ray_texture_coords(_camera(centre, centre + [1, 0, 0]), centre, 3.0))
    assert abs(lon) < 1e-6 and abs(lat) < 1e-6
    # along +y: longitude +90 degrees (grid x = 0.5)
    lon, _ = _centre_pixel(ray_texture_coords(_camera(centre, centre + [0, 1, 0]), centre, 3.0))
    assert lon == pytest.approx(0.5, abs=1e-6)
    # a camera on the sphere at -x looking through the centre sees the far wall at +x (its own wall is behind it)
    lon, lat = _centre_pixel(ray_texture_coords(_camera(centre + [-3, 0, 0], centre), centre, 3.0))
    assert abs(lon) < 1e-6 and abs(lat) < 1e-6
    # straight up: the top row of the texture (grid y = -1)
    up = ray_texture_coords(_camera(centre, centre + [0, 0, 1], size=1, up=(0.0, 1.0, 0.0)), centre, 3.0)
    assert float(up[0, 0, 0, 1]) == pytest.approx(-1.0, abs=1e-6)


def test_rays_that_miss_a_sphere_the_camera_is_outside_of_stay_finite():
    grid = ray_texture_coords(_camera([0, 50, 0], [0, 100, 0], size=16), np.zeros(3), 1.0)  # looking away
    assert torch.isfinite(grid).all() and float(grid.abs().max()) <= 1.0 + 1e-6


def test_the_sphere_goes_through_the_cameras_and_refuses_a_rig_without_one():
    cams = [_camera([4 * math.cos(a), 4 * math.sin(a), 0.3], [0, 0, 0]) for a in np.linspace(0, 2 * math.pi, 6, False)]
    centre, radius = sphere_through(cams)
    assert np.allclose(centre, 0.0, atol=0.1) and radius == pytest.approx(4.0, rel=0.03)
    with pytest.raises(GsgsError, match="no cameras"):
        sphere_through([])
    # parallel axes (a forward-facing rig): centred ahead of the cameras, which it still goes through
    centre, radius = sphere_through([_camera([x, 0, 0], [x, 5, 0]) for x in (-1.0, 0.0, 1.0)])
    assert centre[1] > 0 and radius > 0 and math.isfinite(radius)


@pytest.mark.parametrize("width", [-2, 7, 8, 15, 8194])
def test_a_bad_texture_width_is_refused_with_what_is_allowed(width):
    with pytest.raises(GsgsError, match="even texture width"):
        check_width(width)
    assert check_width(0) == 0 and check_width(64) == 64


def test_a_constant_texture_equal_to_the_background_changes_nothing_and_alpha_gates_the_gradient():
    from gsgs_engine.render.api import RenderOutput

    cam = _camera([4, 0, 0], [0, 0, 0], size=8)
    bg = torch.tensor([0.2, 0.5, 0.7])
    sphere = BackgroundSphere.through([cam, _camera([-4, 0, 0], [0, 0, 0], size=8)], bg.numpy(), width=32)
    colour = torch.rand(8, 8, 3)
    alpha = torch.zeros(8, 8)
    alpha[:, :4] = 1.0  # left half covered by splats, right half open
    out = RenderOutput(color=colour.clone(), depth=torch.zeros(8, 8), alpha=alpha, radii=torch.zeros(0),
                       visible=torch.zeros(0, dtype=torch.bool), means2d=torch.zeros(0, 2), backend="test")
    composited = sphere.composite(out, cam, bg).color
    assert torch.allclose(composited, colour, atol=2e-3)  # the texture starts at the background (logit rounding)
    composited.sum().backward()
    g = sphere.logits.grad
    assert g is not None and torch.isfinite(g).all() and float(g.abs().sum()) > 0
    # covered pixels pass no gradient: a fully covered render leaves the texture untouched
    sphere.logits.grad = None
    out.alpha = torch.ones(8, 8)
    out.color = colour.clone()
    sphere.composite(out, cam, bg).color.sum().backward()
    assert float(sphere.logits.grad.abs().sum()) == 0.0


def test_training_learns_the_texture_and_resumes_it_bit_identically(tmp_path):
    from dataclasses import replace

    # the photos show white behind the object; the run's background starts grey: the open pixels teach the wall
    scene = replace(make_scene(), background=np.full(3, 0.5, np.float32))
    a = make_trainer(scene, tmp_path=tmp_path / "a", iters=40, checkpoint_every=8, seed=3, background_sphere=32)
    a.setup()
    assert a.bg_sphere is not None and a.bg_sphere.size == (32, 16)
    assert torch.allclose(a.bg_sphere.texture(), torch.tensor(0.5))
    a.train()
    assert torch.isfinite(a.bg_sphere.logits).all()
    assert float(a.bg_sphere.texture().detach().max()) > 0.55  # towards the photos' white
    b = make_trainer(scene, tmp_path=tmp_path / "b", iters=40, checkpoint_every=8, seed=3, background_sphere=32)
    b.setup()
    b.train(until=8)
    b.save_checkpoint()
    c = make_trainer(scene, tmp_path=tmp_path / "b", iters=40, checkpoint_every=8, seed=3, background_sphere=32)
    c.setup(resume=True)
    assert torch.equal(c.bg_sphere.logits.detach(), b.bg_sphere.logits.detach())
    c.train()
    assert torch.allclose(c.bg_sphere.logits, a.bg_sphere.logits, atol=1e-5)
    assert torch.allclose(c.model.means, a.model.means, atol=1e-5)


def test_a_sphere_and_a_random_background_together_are_refused():
    from gsgs_engine.train.trainer import TrainConfig, validate_config

    with pytest.raises(GsgsError, match="two backgrounds"):
        validate_config(TrainConfig(background_sphere=64, random_background=True))
    with pytest.raises(GsgsError, match="even texture width"):
        validate_config(TrainConfig(background_sphere=63))
    trainer = make_trainer(iters=4, background_sphere=32, random_background=True)  # a trainer built directly
    with pytest.raises(GsgsError, match="two backgrounds"):
        trainer.setup()


def test_without_the_setting_there_is_no_sphere():
    t = make_trainer(iters=4)
    t.setup()
    t.train()
    assert t.bg_sphere is None and t.bg_optimizer is None and "background_sphere" not in t.state()


def test_the_result_holds_the_texture_and_gsgs_eval_renders_with_it(tmp_path):
    from gsgs_engine.io.scene import Scene
    from gsgs_engine.reconstruct import train_and_export
    from gsgs_engine.train.trainer import TrainConfig

    scene = make_scene()
    config = TrainConfig(iters=12, init="points", sh_degree=1, background_sphere=32, checkpoint_every=0)
    config.densify_config.max_gaussians = 400
    metrics = train_and_export(scene, config, tmp_path / "out", tmp_path / "ckpt")
    record = metrics["plan"]["background_sphere"]
    assert record["file"] == TEXTURE_FILE and (record["width"], record["height"]) == (32, 16)
    assert (tmp_path / "out" / TEXTURE_FILE).is_file()
    back = BackgroundSphere.from_record(record, tmp_path / "out")
    assert np.allclose(back.centre, sphere_through([v.camera for v in scene.train])[0])
    cam = scene.test[0].camera
    assert torch.isfinite(back.image(cam)).all()
    with pytest.raises(GsgsError, match="texture is missing"):
        BackgroundSphere.from_record({**record, "file": "nothing.png"}, tmp_path / "out")
    assert isinstance(scene, Scene) and json.loads((tmp_path / "out" / "metrics.json").read_text())["plan"][
        "background_sphere"] == record


def test_the_effect_plan_names_the_sphere_and_refuses_it_on_rgba_views():
    from dataclasses import replace

    from gsgs_engine.effect_plan import apply_effect_plan, plan_effects, scene_for_plan
    from gsgs_engine.priors.config import PriorConfig
    from gsgs_engine.train.trainer import TrainConfig

    scene = make_scene()
    auto = PriorConfig(prior="auto", num_pseudo=2, rounds=1)
    plan = plan_effects(scene, TrainConfig(init="points"), auto, {"sh_degree": 1, "background": "sphere"},
                        log=lambda m: None)
    assert plan["background"].value == "sphere" and plan["background"].enabled
    assert "sphere through the cameras" in plan["background"].reason
    tc, _ = apply_effect_plan(plan, TrainConfig())
    assert tc.background_sphere == 256 and not tc.random_background
    assert np.allclose(scene_for_plan(scene, plan).background, plan["background"].measured["colour"])
    mean = plan_effects(scene, TrainConfig(init="points"), auto, {"sh_degree": 1, "background": "mean"},
                        log=lambda m: None)
    assert apply_effect_plan(mean, TrainConfig(background_sphere=64))[0].background_sphere == 0
    with pytest.raises(GsgsError, match="alpha channel"):
        plan_effects(replace(scene, has_alpha=True), TrainConfig(init="points"), auto,
                     {"sh_degree": 1, "background": "sphere"}, log=lambda m: None)
