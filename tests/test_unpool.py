"""Proximity-guided unpooling (FSGS): the scores, the pairs, the new rows, training with it and resuming."""

from __future__ import annotations

import pytest
import torch

from gsgs_engine import GsgsError
from gsgs_engine.gaussians import knn_mean_sq_dist, nearest_neighbours
from gsgs_engine.train.techniques.catalogue import make_techniques, parse_techniques
from gsgs_engine.train.techniques.unpool import (ProximityUnpooling, proximity_scores, unpool_pairs,
                                                 unpooled_rows)
from test_trainer import make_scene, make_trainer


def test_nearest_neighbours_match_brute_force_on_both_paths():
    g = torch.Generator().manual_seed(0)
    pts = torch.randn(700, 3, generator=g)  # more than 4 leaves of 128: the kd path
    pts[-3:] *= 50.0  # isolated points: the fallback search
    d2 = torch.cdist(pts.double(), pts.double()).square()
    d2.fill_diagonal_(float("inf"))
    brute = torch.topk(d2, 3, dim=1, largest=False)
    for leaf in (128, 10 ** 9):  # the kd leaves, then one chunked search
        vals, idx = nearest_neighbours(pts, 3, leaf=leaf)
        assert torch.allclose(vals.double(), brute.values, rtol=1e-4, atol=1e-6)
        assert torch.equal(idx, brute.indices)
        assert torch.equal(knn_mean_sq_dist(pts, 3, leaf=leaf), vals.mean(dim=1))
    vals, idx = nearest_neighbours(pts[:1], 3)
    assert vals.shape == (1, 0) and idx.shape == (1, 0)


def test_isolated_points_are_sources_and_each_pair_is_unpooled_once():
    # a dense grid plane at z = 5 seen from a camera at the origin, and two lone points beside it
    xs = torch.linspace(-1, 1, 21)
    grid = torch.stack(torch.meshgrid(xs, xs, indexing="ij"), dim=-1).reshape(-1, 2)
    plane = torch.cat([grid, torch.full((len(grid), 1), 5.0)], dim=1)
    lone = torch.tensor([[3.0, 0.0, 5.0], [3.0, 2.0, 5.0]])
    means = torch.cat([plane, lone])
    score, idx = proximity_scores(means, 3, torch.zeros(1, 3))
    assert torch.isfinite(score).all() and score.shape == (len(means),)
    pairs = unpool_pairs(score, idx, ratio=3.0, limit=100)
    n = len(plane)
    assert set(pairs[:, 0].tolist()) <= {n, n + 1}  # only the lone points are sources
    keys = {tuple(sorted(p)) for p in pairs.tolist()}
    assert len(keys) == len(pairs)  # (a, b) and (b, a) once
    assert (pairs[:, 0] != pairs[:, 1]).all()
    assert pairs[0, 0] == int(score.argmax())  # the most isolated first
    assert len(unpool_pairs(score, idx, ratio=3.0, limit=2)) == 2
    # a far plane of the same angular spacing is not sparse: the score is an angle
    far = plane.clone()
    far[:, :2] *= 10.0
    far[:, 2] = 50.0
    s_far, _ = proximity_scores(torch.cat([plane, far]), 3, torch.zeros(1, 3))
    assert torch.allclose(s_far[:n], s_far[n:], rtol=1e-3)


def test_non_finite_means_are_never_sources_or_destinations():
    g = torch.Generator().manual_seed(1)
    means = torch.rand(50, 3, generator=g) + torch.tensor([0.0, 0.0, 4.0])
    means[3] = float("nan")
    means[7] = float("inf")
    score, idx = proximity_scores(means, 3, torch.zeros(1, 3))
    assert torch.isfinite(score).all() and score[3] == 0 and score[7] == 0
    finite = torch.isfinite(means).all(dim=1)
    pairs = unpool_pairs(score, idx, ratio=0.5, limit=1000, finite=finite)
    assert len(pairs) > 0 and not bool(((pairs == 3) | (pairs == 7)).any())


def test_unpooled_rows_sit_at_the_midpoints_with_the_destinations_size():
    g = torch.Generator().manual_seed(2)
    n = 6
    params = {"means": torch.rand(n, 3, generator=g), "log_scales": torch.rand(n, 3, generator=g),
              "quats": torch.rand(n, 4, generator=g), "opacity_logits": torch.rand(n, generator=g),
              "sh_dc": torch.rand(n, 1, 3, generator=g), "sh_rest": torch.rand(n, 3, 3, generator=g)}
    rows = unpooled_rows(params, torch.tensor([[0, 4], [5, 1]]))
    assert torch.allclose(rows["means"][0], 0.5 * (params["means"][0] + params["means"][4]))
    assert torch.equal(rows["log_scales"][1], params["log_scales"][1])
    assert torch.equal(rows["opacity_logits"], params["opacity_logits"][[4, 1]])
    assert torch.equal(rows["quats"][0], params["quats"][4])
    assert torch.allclose(rows["sh_rest"][1], 0.5 * (params["sh_rest"][5] + params["sh_rest"][1]))


def test_options_are_checked_and_named_in_the_catalogue():
    parsed = parse_techniques("unpool:ratio=2:every=50")
    technique, = make_techniques(parsed)
    assert isinstance(technique, ProximityUnpooling) and technique.ratio == 2.0 and technique.every == 50
    for bad in ({"every": 0}, {"until": 0.0}, {"k": 0}, {"ratio": 0.0}, {"max_fraction": 1.5},
                {"min_opacity": 1.0}):
        with pytest.raises(GsgsError, match="unpool"):
            ProximityUnpooling(**bad)


def _trainer(tmp_path, iters, resume=False, until=None):
    trainer = make_trainer(tmp_path=tmp_path, iters=iters, densify=True, checkpoint_every=10, seed=5)
    trainer.setup(resume=resume)
    tech = trainer.add_technique(ProximityUnpooling(every=5, until=0.8, ratio=1.0, max_fraction=0.2))
    trainer.train(until=until)
    return trainer, tech


@pytest.mark.slow  # tens of steps of the tiny scene
def test_training_with_unpooling_adds_gaussians_within_the_budget_and_resumes_to_the_bit(tmp_path):
    straight, tech = _trainer(tmp_path / "a", iters=30)
    assert tech.events > 0 and tech.added > 0, tech.report()
    assert straight.model.num_gaussians <= straight.config.densify_config.max_gaussians
    assert straight.model.all_finite() and straight.nan_steps_skipped == 0
    assert straight.stats.grad_accum.shape[0] == straight.model.num_gaussians
    _trainer(tmp_path / "b", iters=30, until=20)  # stopped after the checkpoint of step 20
    resumed, tech_b = _trainer(tmp_path / "b", iters=30, resume=True)
    assert resumed.step == 30 and tech_b.report() == tech.report()
    for name, value in straight.model.params.items():
        assert torch.equal(value, resumed.model.params[name]), name


def test_unpooling_refuses_a_4d_scene():
    scene = make_scene()
    for v in scene.views:
        v.camera = type(v.camera)(**{**v.camera.__dict__, "time": 0.5})
    trainer = make_trainer(scene, iters=4)
    trainer.setup()
    with pytest.raises(GsgsError, match="4D"):
        trainer.add_technique(ProximityUnpooling())


def test_faded_gaussians_are_neither_sources_nor_destinations():
    trainer = make_trainer(scene=make_scene(), iters=1, densify=True)
    trainer.setup()
    with torch.no_grad():
        trainer.model.params["opacity_logits"][::2] = -6.0  # every second Gaussian faded (opacity 0.0025)
        trainer.model.params["opacity_logits"][1::2] = 3.0  # the others opaque (0.95)
    faded = trainer.model.opacities.detach() < 0.5
    tech = trainer.add_technique(ProximityUnpooling(every=1, until=1.0, ratio=0.5, max_fraction=1.0,
                                                    min_opacity=0.5))
    trainer.schedule.densify_from = 0
    trainer.config.iters = 5
    trainer.config.densify_config.max_gaussians = 10 ** 6
    n = trainer.model.num_gaussians
    params = {k: v.detach().clone() for k, v in trainer.model.params.items()}
    tech.after_step(trainer, 1)
    assert tech.added > 0 and trainer.model.num_gaussians == n + tech.added
    new_opacity = trainer.model.params["opacity_logits"].detach()[n:]
    assert bool((new_opacity > -6.0).all())  # every destination was an opaque one
    mids = trainer.model.means.detach()[n:]
    opaque = params["means"][~faded]
    # each new mean is the midpoint of two opaque Gaussians
    all_mids = 0.5 * (opaque[:, None, :] + opaque[None, :, :]).reshape(-1, 3)
    gap = (mids[:, None, :] - all_mids[None, :, :]).abs().amax(dim=2).min(dim=1).values
    assert bool((gap < 1e-6).all())


def test_a_scene_with_no_room_adds_nothing():
    trainer = make_trainer(scene=make_scene(), iters=1, densify=True)
    trainer.setup()
    trainer.config.densify_config.max_gaussians = trainer.model.num_gaussians
    tech = trainer.add_technique(ProximityUnpooling(every=1, until=1.0, ratio=0.1))
    n = trainer.model.num_gaussians
    trainer.schedule.densify_from = 0
    trainer.config.iters = 5
    tech.after_step(trainer, 1)
    assert trainer.model.num_gaussians == n and tech.added == 0 and tech.events == 1
