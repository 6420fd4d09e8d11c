"""Algorithm 1 end to end on tiny scenes: plan resolution, rounds on disk, prior loss terms."""

from __future__ import annotations

import json

import pytest
import torch

from gsgs_engine import GsgsError
from gsgs_engine.priors.config import PriorConfig, resolve_prior_plan
from gsgs_engine.train.techniques.prior_loop import recovered_round_steps, round_steps
from gsgs_engine.reconstruct import run_prior_training
from gsgs_engine.train.schedule import Schedule
from gsgs_engine.train.trainer import TrainConfig
from test_trainer import make_scene


def test_plan_auto_without_weights_is_warp_inpaint_with_sparse_depth():
    plan = resolve_prior_plan(PriorConfig(prior="auto"), 8)
    assert plan["generator"] == "warp-inpaint" and plan["depth_source"] == "sparse"
    assert "no diffusion weights" in plan["generator_reason"]


def test_plan_with_diffusion_folders_picks_diffusion(tmp_path):
    (tmp_path / "sd").mkdir()
    (tmp_path / "ad").mkdir()
    cfg = PriorConfig(prior="auto", diffusion_model=str(tmp_path / "sd"), depth_adapter=str(tmp_path / "ad"))
    plan = resolve_prior_plan(cfg, 3)
    assert plan["generator"] == "diffusion" and plan["geo_loss"] is True
    assert resolve_prior_plan(PriorConfig(prior="auto", diffusion_model=str(tmp_path / "sd"), depth_adapter=str(tmp_path / "ad"),
                                          geo_loss=False), 3)["geo_loss"] is False


def test_plan_switches_and_errors():
    assert resolve_prior_plan(PriorConfig(prior="none"), 3)["generator"] is None
    assert resolve_prior_plan(PriorConfig(prior="warp", depth_reg=False), 3)["depth_source"] is None
    depth_only = resolve_prior_plan(PriorConfig(prior="depth"), 3)
    assert depth_only["generator"] is None and depth_only["depth_source"] == "sparse" and depth_only["pseudo_views"] == 0
    with pytest.raises(GsgsError, match="diffusion"):
        resolve_prior_plan(PriorConfig(prior="diffusion"), 3)
    with pytest.raises(GsgsError, match="depth source"):
        resolve_prior_plan(PriorConfig(prior="depth", depth_source="none"), 3)
    with pytest.raises(GsgsError, match="choose one of"):
        resolve_prior_plan(PriorConfig(prior="magic"), 3)


def test_round_steps_follow_the_warmup():
    assert round_steps(1000, 0.3, 3) == [300, 533, 766]
    assert round_steps(10, 0.5, 0) == []
    assert all(0 < s < 5 for s in round_steps(5, 0.3, 4))


def test_rounds_never_follow_an_opacity_reset_closely():
    sched = Schedule.scaled(1000)  # resets every 100 steps up to step 500
    assert (sched.opacity_reset_every, sched.densify_until) == (100, 500)
    assert recovered_round_steps(round_steps(1000, 0.3, 3), sched) == [375, 575, 766]
    for s in recovered_round_steps(round_steps(300, 0.3, 2), Schedule.scaled(300)):
        every = Schedule.scaled(300).opacity_reset_every
        assert s % every >= (3 * every) // 4 or s > Schedule.scaled(300).densify_until + (3 * every) // 4 - 1


def test_warp_prior_runs_rounds_and_adds_terms(tmp_path):
    scene = make_scene(n_train=3, n_test=1)
    cfg = TrainConfig(iters=40, backend="reference", init="points", sh_degree=0, checkpoint_every=0)
    prior = PriorConfig(prior="warp", num_pseudo=3, rounds=2, warmup_fraction=0.5)
    metrics = run_prior_training(scene, cfg, prior, tmp_path / "out", tmp_path / "ckpt")
    plan = metrics["plan"]["prior_plan"]
    assert plan["generator"] == "warp-inpaint" and plan["depth_source"] == "sparse" and plan["round_steps"] == [20, 30]
    assert len(metrics["prior_rounds"]) == 2
    for k in (0, 1):
        folder = tmp_path / "out" / "pseudo" / f"round_{k}"
        assert len(list(folder.glob("pseudo_*_render.png"))) == 3
        info = json.loads((folder / "round.json").read_text())
        assert len(info["views"]) == 3 and "nearest_train" in info["views"][0]
    assert "pseudo_l1" in metrics["final_losses"] and "depth_reg" in metrics["final_losses"]
    assert metrics["nan_steps_skipped"] == 0 and metrics["iterations"] == 40
    assert metrics["phase_seconds"]["prior_render"] > 0
    saved = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert saved["plan"]["prior_plan"]["prior"] == "warp"


def test_depth_only_prior_regularises_without_pseudo_views(tmp_path):
    scene = make_scene(n_train=3, n_test=1)
    cfg = TrainConfig(iters=12, backend="reference", init="points", sh_degree=0, checkpoint_every=0)
    metrics = run_prior_training(scene, cfg, PriorConfig(prior="depth"), tmp_path / "o", tmp_path / "c")
    assert "depth_reg" in metrics["final_losses"] and "pseudo_l1" not in metrics["final_losses"]
    assert not (tmp_path / "o" / "pseudo").exists()
    assert torch.isfinite(torch.tensor(metrics["final_losses"]["depth_reg"]))


@pytest.mark.slow
def test_diffusion_prior_end_to_end_with_tiny_models(tmp_path):
    pytest.importorskip("diffusers")
    from gsgs_engine.priors.tiny_diffusion import save_tiny_diffusion

    sd, adapter = save_tiny_diffusion(tmp_path / "models")
    scene = make_scene(n_train=2, n_test=1)
    cfg = TrainConfig(iters=10, backend="reference", init="points", sh_degree=0, checkpoint_every=0)
    prior = PriorConfig(prior="auto", diffusion_model=str(sd), depth_adapter=str(adapter), num_pseudo=2, rounds=1,
                        warmup_fraction=0.5, device="cpu",
                        diffusion={"resolution": 32, "steps": 2, "lora_steps": 2})
    metrics = run_prior_training(scene, cfg, prior, tmp_path / "out", tmp_path / "ckpt")
    plan = metrics["plan"]["prior_plan"]
    assert plan["prior"] == "auto:diffusion" and plan["geo_loss"] is True
    (rnd,) = metrics["prior_rounds"]
    assert rnd["lora"]["geo"] >= 0 and rnd["lora"]["ldm"] > 0
    assert (tmp_path / "out" / "pseudo" / "round_0" / "lora.safetensors").is_file()
    assert metrics["phase_seconds"]["prior_adapt"] > 0 and metrics["nan_steps_skipped"] == 0


def test_depth_term_is_dropped_when_the_sparse_depth_covers_too_little(tmp_path):
    scene = make_scene(n_train=3, n_test=1)
    scene.points = scene.points[:2000:40]  # a handful of points: a few pixels of depth per view
    scene.point_colors = scene.point_colors[:2000:40]
    cfg = TrainConfig(iters=6, backend="reference", init="points", sh_degree=0, checkpoint_every=0)
    cfg.min_init_points = 1
    metrics = run_prior_training(scene, cfg, PriorConfig(prior="warp", num_pseudo=2, rounds=1, warmup_fraction=0.5),
                                 tmp_path / "o", tmp_path / "c")
    plan = metrics["plan"]["prior_plan"]
    assert plan["depth_coverage"] < 0.10 and "covers" in plan["depth_source_disabled"]
    assert "depth_reg" not in metrics["final_losses"] and "pseudo_l1" in metrics["final_losses"]


def test_empty_pixels_of_pseudo_views_get_gaussians_in_photo_scenes(tmp_path):
    from gsgs_engine.train.techniques.prior_loop import PriorLoop
    from gsgs_engine.priors.warp import project
    from test_trainer import make_trainer

    trainer = make_trainer(iters=40, backend="reference", sh_degree=1)
    trainer.setup()
    prior = PriorConfig(prior="warp", num_pseudo=3, rounds=1, depth_reg=False)
    loop = PriorLoop(prior, resolve_prior_plan(prior, 3), tmp_path, log=lambda m: None)
    trainer.add_technique(loop)
    assert loop.fill_empty  # RGB views: empty pixels are unseen content, not background
    with torch.no_grad():
        renders = [trainer.render(p.camera) for p in loop.pseudo]
    empty = [(r.alpha <= 0.5) for r in renders]
    assert any(bool(e.any()) for e in empty)
    images = [r.color.clone() for r in renders]
    n0 = trainer.model.num_gaussians
    added = loop._fill_empty_with_gaussians(renders, images)
    model = trainer.model
    assert added > 0 and model.num_gaussians == n0 + added
    assert trainer.stats.grad_accum.shape[0] == model.num_gaussians
    for group in trainer.optimizer.param_groups:
        assert group["params"][0].shape[0] == model.num_gaussians
    assert model.all_finite()
    # every new Gaussian sits in front of some pseudo camera, on the ray of one of its empty pixels
    new = model.means.detach()[n0:]
    hits = torch.zeros(added, dtype=torch.bool)
    for p, e in zip(loop.pseudo, empty):
        uv, z = project(p.camera, new)
        u, v = uv[:, 0].floor().long(), uv[:, 1].floor().long()
        inside = (z > 0) & (u >= 0) & (u < e.shape[1]) & (v >= 0) & (v < e.shape[0])
        hits[inside] |= e[v[inside], u[inside]]
    assert bool(hits.all())
    assert trainer.train_step()  # the optimiser takes the grown model
    # the model's size cap holds: seeding fills the room left and no more
    trainer.config.densify_config.max_gaussians = model.num_gaussians + 3
    assert loop._fill_empty_with_gaussians(renders, images) == 3
    assert loop._fill_empty_with_gaussians(renders, images) == 0
    assert model.num_gaussians == trainer.config.densify_config.max_gaussians


def test_seeding_is_bounded_per_round_and_coarser_at_high_resolution(tmp_path, monkeypatch):
    """A 514-Gaussian photo model at 1600 px once got 610k seeds in one round (issue 15)."""
    from dataclasses import replace as dc_replace

    import gsgs_engine.train.techniques.prior_loop as prior_loop
    from gsgs_engine.train.techniques.prior_loop import PriorLoop, seed_stride
    from test_trainer import make_trainer

    cam = make_trainer().scene.views[0].camera
    assert seed_stride(dc_replace(cam, width=504, height=378)) == 4  # llff_flower's size: unchanged
    assert seed_stride(dc_replace(cam, width=1600, height=871)) == 12
    trainer = make_trainer(iters=40, backend="reference", sh_degree=1)
    trainer.setup()
    prior = PriorConfig(prior="warp", num_pseudo=3, rounds=1, depth_reg=False)
    loop = PriorLoop(prior, resolve_prior_plan(prior, 3), tmp_path, log=lambda m: None)
    trainer.add_technique(loop)
    with torch.no_grad():
        renders = [trainer.render(p.camera) for p in loop.pseudo]
    images = [r.color.clone() for r in renders]
    monkeypatch.setattr(prior_loop, "SEED_ROUND_MIN", 5)
    n0 = trainer.model.num_gaussians
    added = loop._fill_empty_with_gaussians(renders, images, stride=1)
    assert added == min(n0, sum(int((r.alpha <= 0.5).sum()) for r in renders))  # at most the model's own size
    assert trainer.model.num_gaussians == n0 + added <= 2 * n0


def test_prior_flags_reach_the_config_and_the_plan():
    import argparse

    from gsgs_engine.priors.config import add_prior_arguments, prior_config_from_args

    parser = argparse.ArgumentParser()
    parser.add_argument("--prior", default="none")
    add_prior_arguments(parser)
    cfg = prior_config_from_args(parser.parse_args(["--prior", "warp", "--pseudo-reach", "2.5", "--pseudo-views", "6"]))
    assert (cfg.prior, cfg.reach, cfg.num_pseudo) == ("warp", 2.5, 6)
    assert prior_config_from_args(parser.parse_args([])).reach == PriorConfig.reach == 5.0
    assert prior_config_from_args(parser.parse_args(["--ring-weight", "0.3"])).ring_weight == 0.3
    assert prior_config_from_args(parser.parse_args([])).ring_weight is None
    assert prior_config_from_args(parser.parse_args(["--ring-fraction", "0.5"])).ring_fraction == 0.5
    plan = resolve_prior_plan(cfg, 3)
    assert plan["reach"] == 2.5 and plan["pseudo_views"] == 6


def test_ring_views_take_their_own_loss_weight(tmp_path):
    import numpy as np

    from gsgs_engine.io.scene import Scene, View
    from gsgs_engine.train.techniques.prior_loop import PriorLoop
    from test_trainer import ground_truth_gaussians, look_at, make_trainer, render_ground_truth

    # a forward-facing rig: three cameras side by side, parallel axes, the content 4 units ahead
    gt = ground_truth_gaussians()
    cams = [look_at((x, -4.0, 0.0), (x, 0.0, 0.0), name=f"f{k}") for k, x in enumerate((-0.4, 0.0, 0.4, 0.2))]
    views = [View(camera=c, image_path=None, loader=lambda img=render_ground_truth(gt, c): img) for c in cams]
    pts = np.concatenate([gt["means"].numpy()] * 3)
    scene = Scene(views=views, splits={"train": [0, 1, 2], "test": [3]}, source="synthetic", format="test",
                  points=pts, point_colors=np.full((len(pts), 3), 0.5, np.float32))
    trainer = make_trainer(scene, iters=40, backend="reference", sh_degree=0)
    trainer.setup()
    prior = PriorConfig(prior="warp", num_pseudo=4, rounds=1, depth_reg=False, pseudo_weight=0.1, ring_weight=0.3,
                        ring_fraction=0.5)
    plan = resolve_prior_plan(prior, 3)
    assert plan["pseudo_weight"] == 0.1 and plan["ring_weight"] == 0.3
    loop = PriorLoop(prior, plan, tmp_path, log=lambda m: None)
    trainer.add_technique(loop)
    sources = [p.source for p in loop.pseudo]
    assert sources.count("surrounding") == 2 and sources.count("interpolated") == 2  # a forward-facing rig
    loop.run_round()
    weights = {v.name: v.weight for v in loop.supervision.views}
    for p in loop.pseudo:
        if p.name in weights:
            assert weights[p.name] == (0.3 if p.source == "surrounding" else 0.1)
    assert set(weights.values()) == {0.1, 0.3}
    # unset, the ring shares the pseudo weight
    assert resolve_prior_plan(PriorConfig(prior="warp", pseudo_weight=0.2), 3)["ring_weight"] == 0.2
    # the ring's share of the pseudo views
    for fraction, ring in ((1.0, 4), (0.0, 0), (0.3, 1)):
        prior = PriorConfig(prior="warp", num_pseudo=4, rounds=1, depth_reg=False, ring_fraction=fraction)
        loop = PriorLoop(prior, resolve_prior_plan(prior, 3), tmp_path, log=lambda m: None)
        trainer.techniques = [t for t in trainer.techniques if t.name not in ("gsgs_prior", "pseudo_views")]
        trainer.add_technique(loop)
        assert [p.source for p in loop.pseudo].count("surrounding") == ring and len(loop.pseudo) == 4
