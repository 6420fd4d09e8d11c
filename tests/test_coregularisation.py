"""Co-regularisation (CoR-GS) as a technique: the neighbour test, both fields training, co-pruning, resume."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from gsgs_engine import GsgsError
from gsgs_engine.train.techniques.coregularisation import CoRegularisation, isolated
from test_trainer import make_scene, make_trainer


def test_isolated_never_removes_a_point_with_a_neighbour_within_the_radius():
    g = torch.Generator().manual_seed(0)
    points = torch.rand(400, 3, generator=g) * 4.0
    others = torch.rand(300, 3, generator=g) * 4.0
    radius = 0.3
    mask = isolated(points, others, radius)
    nearest = torch.cdist(points.double(), others.double()).min(dim=1).values
    assert not bool((mask & (nearest <= radius)).any())  # every point with a close neighbour is kept
    assert bool((nearest[mask] > radius).all())
    # and the test is not vacuous: far points are found (nearest beyond the 27-cell block)
    assert bool(mask[nearest > 2 * np.sqrt(3) * radius].all()) and int(mask.sum()) > 0


def test_isolated_edge_cases():
    pts = torch.tensor([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]])
    assert isolated(pts, torch.zeros(0, 3), 1.0).tolist() == [True, True]
    assert isolated(torch.zeros(0, 3), pts, 1.0).shape == (0,)
    assert isolated(pts, torch.tensor([[0.5, 0.0, 0.0]]), 1.0).tolist() == [False, True]
    with pytest.raises(GsgsError, match="radius"):
        isolated(pts, pts, 0.0)


def _run(tmp_path, iters, until=None, resume=False, **kw):
    trainer = make_trainer(tmp_path=tmp_path, iters=iters, checkpoint_every=10, seed=3)
    trainer.setup(resume=resume)
    tech = trainer.add_technique(CoRegularisation(start_fraction=0.25, prune_every=kw.pop("prune_every", 10), **kw))
    trainer.train(until=until)
    return trainer, tech


def test_both_fields_train_and_agree_at_pseudo_views(tmp_path):
    trainer, tech = _run(tmp_path, iters=20)
    partner = tech.partner
    assert trainer.step == partner.step == 20
    assert {"coreg_l1", "coreg_dssim"} <= set(trainer.last_losses) and "coreg_l1" in partner.last_losses
    assert trainer.model.all_finite() and partner.model.all_finite()
    assert trainer.nan_steps_skipped == partner.nan_steps_skipped == 0
    # the two fields follow their own random streams: they differ, yet render alike at a pseudo view
    assert not torch.equal(trainer.model.means.detach(), partner.model.means.detach())
    cam = tech.pool[0]
    with torch.no_grad():
        diff = (trainer.render(cam).color - partner.render(cam).color).abs().mean()
    assert float(diff) < 0.1
    report = tech.report()
    assert report["start_step"] == 5 and report["partner_gaussians"] == partner.model.num_gaussians


def test_co_pruning_removes_what_only_one_field_has(tmp_path):
    from gsgs_engine.train.densify import append_gaussians

    trainer = make_trainer(tmp_path=None, iters=12, seed=3)
    trainer.setup()
    tech = trainer.add_technique(CoRegularisation(start_fraction=1.0, prune_every=5))  # densify_until is 6
    far = {k: v[:1].detach().clone() for k, v in trainer.model.params.items()}
    far["means"] = torch.tensor([[50.0, 50.0, 50.0]], device=trainer.device)  # a Gaussian the partner lacks
    append_gaussians(trainer.model, trainer.optimizer, far)
    trainer.stats.grow(1)
    trainer.train()
    assert tech.pruned["main"] >= 1
    assert not bool((trainer.model.means.detach().cpu() - torch.tensor([50.0, 50.0, 50.0])).norm(dim=1).lt(1.0).any())
    assert trainer.model.num_gaussians == len(trainer.stats.grad_accum)
    for group in trainer.optimizer.param_groups:
        state = trainer.optimizer.state.get(group["params"][0], {})
        if state:
            assert state["exp_avg"].shape == group["params"][0].shape


def test_resume_continues_both_fields_bit_identically(tmp_path):
    whole, _ = _run(tmp_path / "a", iters=30)
    first, _ = _run(tmp_path / "b", iters=30, until=20)  # checkpoints at 10 and 20 (main and partner)
    assert (tmp_path / "b" / "ckpt" / "coregularisation").is_dir()
    resumed, tech = _run(tmp_path / "b", iters=30, resume=True)
    assert tech.partner.step == 30 and resumed.step == 30
    for name, p in whole.model.params.items():
        assert torch.equal(resumed.model.params[name].detach(), p.detach()), name


def test_refuses_scenes_with_time():
    scene = make_scene()
    for v in scene.views:
        v.camera = type(v.camera)(**{**v.camera.__dict__, "time": 0.5})
    assert scene.has_time
    trainer = make_trainer(scene, iters=4)
    trainer.setup()
    with pytest.raises(GsgsError, match="4D"):
        trainer.add_technique(CoRegularisation())


def test_switched_on_by_name_with_options():
    from gsgs_engine.train.techniques.catalogue import make_techniques, parse_techniques

    parsed = parse_techniques("coregularisation:weight=0.5:prune_every=250,dropout")
    assert [p["name"] for p in parsed] == ["dropout", "coregularisation"]
    tech = make_techniques(parsed)[1]
    assert isinstance(tech, CoRegularisation) and tech.weight == 0.5 and tech.prune_every == 250
    with pytest.raises(GsgsError, match="no option"):
        parse_techniques("coregularisation:log=1")


def _run_named(tmp_path, iters, spec, until=None, resume=False):
    from gsgs_engine.train.techniques.catalogue import make_techniques, parse_techniques

    trainer = make_trainer(tmp_path=tmp_path, iters=iters, checkpoint_every=10, seed=3)
    trainer.setup(resume=resume)
    for technique in make_techniques(parse_techniques(spec)):
        trainer.add_technique(technique)
    trainer.train(until=until)
    return trainer, trainer.technique("coregularisation")


def test_the_partner_trains_with_the_runs_other_techniques_and_resumes_with_them(tmp_path):
    spec = "count_control,dropout,opacity_decay,coregularisation:start_fraction=0.25:prune_every=10"
    whole, tech = _run_named(tmp_path / "a", 30, spec)
    names = [t.name for t in tech.partner.techniques]
    assert names == ["count_control", "dropout", "opacity_decay", "coregularisation_mirror"]
    assert all(t is not p for t in whole.techniques for p in tech.partner.techniques)  # its own instances
    # the partner's settings are its own copy: its techniques adjust them (count_control lowers the densifier's
    # max_gaussians at install) without touching the main field's
    assert tech.partner.config.densify_config is not whole.config.densify_config
    assert tech.partner.config.densify_config.max_gaussians == whole.config.densify_config.max_gaussians
    _run_named(tmp_path / "b", 30, spec, until=20)
    resumed, rtech = _run_named(tmp_path / "b", 30, spec, resume=True)
    assert rtech.partner.step == 30
    for name, p in whole.model.params.items():
        assert torch.equal(resumed.model.params[name].detach(), p.detach()), name
    for name, p in tech.partner.model.params.items():
        assert torch.equal(rtech.partner.model.params[name].detach(), p.detach()), name
