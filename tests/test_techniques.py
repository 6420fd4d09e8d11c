"""Weights-free sparse-view techniques (issue 14): each changes what it should, runs resume
bit-identically with them on, the switch validates names, and the trainer names none of them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from gsgs_engine import GsgsError
from gsgs_engine.train.technique import StepContext
from test_trainer import Probe, look_at, make_scene, make_trainer

REPO = Path(__file__).resolve().parents[1]


def ctx_for(trainer, step: int, view: int = 0) -> StepContext:
    return StepContext(trainer, step, view, None, trainer._targets[view], trainer.background)


# -- dropout ----------------------------------------------------------------------------------
def test_dropout_changes_training_renders_only():
    from gsgs_engine.train.techniques.dropout import GaussianDropout

    trainer = make_trainer(iters=100)
    trainer.setup()
    trainer.add_technique(GaussianDropout())
    cam = trainer.train_views[0].camera
    with torch.no_grad():
        plain = trainer.render(cam).color.clone()
        late = trainer.render_for_training(ctx_for(trainer, 100), cam).color
        first = trainer.render_for_training(ctx_for(trainer, 0), cam).color  # p = 0 before training
        again = trainer.render(cam).color
    assert not torch.allclose(late, plain, atol=1e-4), "a training render at p = 0.2 must differ"
    assert torch.equal(first, plain), "p = 0 leaves the render as it is"
    assert torch.equal(again, plain), "evaluation renders use every Gaussian"


def test_dropout_is_unbiased_and_ramps():
    from gsgs_engine.train.techniques.dropout import drop_rate, dropout_opacities

    assert drop_rate(0, 1000) == 0.0 and drop_rate(500, 1000) == pytest.approx(0.1)
    assert drop_rate(1000, 1000) == pytest.approx(0.2) and drop_rate(2000, 1000) == pytest.approx(0.2)
    g = torch.Generator().manual_seed(3)
    o = torch.rand(200_000, generator=torch.Generator().manual_seed(1))
    d = dropout_opacities(o, 0.2, g)
    kept = d > 0
    assert abs(1 - kept.float().mean().item() - 0.2) < 0.005
    assert torch.allclose(d[kept], o[kept] / 0.8)
    assert d.mean().item() == pytest.approx(o.mean().item(), rel=0.01)  # unbiased mean opacity


def test_sh_band_dropout_truncates_whole_bands_from_the_top():
    from gsgs_engine.train.techniques.dropout import dropout_sh_bands

    n = 100_000
    sh = torch.rand(n, 9, 3, generator=torch.Generator().manual_seed(1)) + 0.5  # degree 2, no zero coefficient
    out = dropout_sh_bands(sh, 0.2, torch.Generator().manual_seed(2))
    band1, band2 = (out[:, 1:4] != 0).all(dim=(1, 2)), (out[:, 4:9] != 0).all(dim=(1, 2))
    assert torch.equal(out[:, 0], sh[:, 0])  # the base colour stays
    assert ((out[:, 1:4] == 0).all(dim=(1, 2)) | band1).all() and ((out[:, 4:9] == 0).all(dim=(1, 2)) | band2).all()
    assert not (band2 & ~band1).any()  # a dropped band drops the bands above it
    assert band1.float().mean().item() == pytest.approx(0.8, abs=0.01)
    assert band2.float().mean().item() == pytest.approx(0.64, abs=0.01)
    assert torch.equal(out[band2], sh[band2])  # kept bands are not rescaled
    # nothing to drop at degree 0 or rate 0; gradients flow to the kept coefficients only
    assert torch.equal(dropout_sh_bands(sh[:, :1], 0.2, torch.Generator()), sh[:, :1])
    assert dropout_sh_bands(sh, 0.0, torch.Generator()) is sh
    leaf = sh[:50].clone().requires_grad_(True)
    dropout_sh_bands(leaf, 0.5, torch.Generator().manual_seed(0)).sum().backward()
    assert torch.isfinite(leaf.grad).all() and set(leaf.grad.unique().tolist()) <= {0.0, 1.0}


def test_sh_band_dropout_option_changes_training_renders_only():
    from gsgs_engine.train.techniques.catalogue import make_techniques, parse_techniques

    trainer = make_trainer(iters=100, sh_degree=1)
    trainer.setup()
    trainer.model.raise_sh_degree()
    with torch.no_grad():
        trainer.model.params["sh_rest"].normal_(0.0, 0.3, generator=torch.Generator().manual_seed(0))
    (tech,) = make_techniques(parse_techniques("dropout:sh_rate=0.5:max_rate=0.0"))
    trainer.add_technique(tech)
    cam = trainer.train_views[0].camera
    with torch.no_grad():
        plain = trainer.render(cam).color.clone()
        training = trainer.render_for_training(ctx_for(trainer, 50), cam).color
    assert not torch.allclose(training, plain, atol=1e-4) and torch.isfinite(training).all()
    assert torch.equal(trainer.render(cam).color, plain)
    assert tech.report()["sh_rate"] == 0.5
    with pytest.raises(GsgsError, match="sh_rate"):
        make_techniques(parse_techniques("dropout:sh_rate=1.0"))


def test_density_guided_dropout_drops_crowds_more_and_stays_unbiased():
    from gsgs_engine.train.techniques.dropout import guided_dropout_opacities, neighbourhood_density

    g = torch.Generator().manual_seed(0)
    crowd = torch.randn(4000, 3, generator=g) * 0.01  # a tight cluster
    spread = torch.rand(4000, 3, generator=g) * 10.0 - 5.0  # the same count over a large box
    means = torch.cat([crowd, spread])
    density = neighbourhood_density(means)
    assert density.shape == (8000,) and bool(((density >= 0) & (density <= 1)).all())
    assert density[:4000].mean() > 0.7 > 0.3 > density[4000:].mean()
    # scale-free: the same layout in micrometres or kilometres gives the same percentiles
    assert torch.equal(neighbourhood_density(means * 1e-6), density)
    assert torch.equal(neighbourhood_density(means * 1e6), density)

    o = torch.full((8000,), 0.5)
    dropped_crowd = dropped_spread = 0.0
    total = torch.zeros(8000)
    for seed in range(50):
        d = guided_dropout_opacities(o, 0.2, density, torch.Generator().manual_seed(seed))
        dropped_crowd += (d[:4000] == 0).float().mean().item() / 50
        dropped_spread += (d[4000:] == 0).float().mean().item() / 50
        total += d / 50
    assert dropped_crowd > 2 * dropped_spread
    assert (dropped_crowd + dropped_spread) / 2 == pytest.approx(0.2, abs=0.01)  # the schedule's mean rate
    assert total.mean().item() == pytest.approx(0.5, rel=0.01)  # unbiased mean opacity
    assert guided_dropout_opacities(o, 0.0, density, g) is o


def test_anchor_dropout_drops_whole_neighbourhoods_unbiased():
    from gsgs_engine.train.techniques.dropout import anchor_dropout_opacities, voxel_cells

    g = torch.Generator().manual_seed(1)
    means = torch.rand(20_000, 3, generator=g)
    cells = voxel_cells(means)
    assert cells.shape == (20_000,) and int(cells.min()) == 0
    counts = torch.bincount(cells)
    assert 4 <= counts.float().mean().item() <= 16  # about VOXEL_OCCUPANCY on an even spread
    o = torch.rand(20_000, generator=g)
    d = anchor_dropout_opacities(o, 0.2, cells, torch.Generator().manual_seed(2))
    dropped = (d == 0)
    # a voxel goes whole or not at all
    per_cell = torch.zeros(len(counts)).index_add_(0, cells, dropped.float())
    assert bool(((per_cell == 0) | (per_cell == counts.float())).all())
    assert abs(dropped.float().mean().item() - 0.2) < 0.02
    assert torch.allclose(d[~dropped], o[~dropped] / 0.8)
    assert anchor_dropout_opacities(o, 0.0, cells, g) is o


def test_guided_dropout_without_a_camera_keeps_its_guide():
    """A step context without a camera (the trainer always names one): anchor still drops whole voxels, density
    falls back to the neighbourhood term alone, neither to the uniform mask."""
    from gsgs_engine.train.techniques.dropout import GaussianDropout, voxel_cells

    trainer = make_trainer(iters=100)
    trainer.setup()
    n = trainer.model.num_gaussians
    inputs = {"means": trainer.model.means.detach(), "opacities": torch.full((n,), 0.5)}
    out = GaussianDropout(guide="anchor").render_inputs(ctx_for(trainer, 100), inputs)["opacities"]
    cells = voxel_cells(inputs["means"])
    dropped = torch.zeros(int(cells.max()) + 1).index_add_(0, cells, (out == 0).float())
    counts = torch.bincount(cells).float()
    assert bool(((dropped == 0) | (dropped == counts)).all()) and bool((out == 0).any())
    dense = GaussianDropout(guide="density").render_inputs(ctx_for(trainer, 100), inputs)["opacities"]
    assert torch.isfinite(dense).all() and bool((dense == 0).any())


def test_density_guided_dropout_makes_its_nearness_once_a_step(monkeypatch):
    """Every render of a step passes the same means and names the step's camera: the nearness is made once and
    the masks are those of a fresh computation; a new step, camera or set of means makes it again."""
    import gsgs_engine.train.techniques.dropout as dropout_module

    trainer = make_trainer(iters=100)
    trainer.setup()
    calls = []
    real = dropout_module.nearness
    monkeypatch.setattr(dropout_module, "nearness", lambda m, c: calls.append(1) or real(m, c))
    means = trainer.model.means.detach()
    n = means.shape[0]
    ctx = ctx_for(trainer, 100)
    ctx.camera = trainer.train_views[0].camera
    drop = dropout_module.GaussianDropout(guide="density")
    outs = []
    for _ in range(3):
        trainer.torch_gen.manual_seed(7)
        outs.append(drop.render_inputs(ctx, {"means": means, "opacities": torch.full((n,), 0.5)})["opacities"])
    assert len(calls) == 1 and all(torch.equal(o, outs[0]) for o in outs)
    fresh = dropout_module.GaussianDropout(guide="density")
    trainer.torch_gen.manual_seed(7)
    assert torch.equal(fresh.render_inputs(ctx, {"means": means, "opacities": torch.full((n,), 0.5)})["opacities"],
                       outs[0])
    drop.render_inputs(ctx, {"means": means.clone(), "opacities": torch.full((n,), 0.5)})
    ctx.step += 1
    drop.render_inputs(ctx, {"means": means, "opacities": torch.full((n,), 0.5)})
    ctx.camera = trainer.train_views[1].camera
    drop.render_inputs(ctx, {"means": means, "opacities": torch.full((n,), 0.5)})
    assert len(calls) == 2 + 3  # the fresh technique's, then one for each change


def test_density_guided_dropout_survives_degenerate_centres():
    from gsgs_engine.train.techniques.dropout import guided_dropout_opacities, nearness, neighbourhood_density
    from test_trainer import look_at

    from gsgs_engine.train.techniques.dropout import voxel_cells

    same = torch.zeros(500, 3)  # every centre at one point
    assert torch.isfinite(neighbourhood_density(same)).all()
    assert int(voxel_cells(same).max()) == 0  # one voxel
    bad = torch.randn(500, 3)
    bad[::7] = float("nan")
    bad[1::7] = float("inf")
    density = neighbourhood_density(bad)
    assert torch.isfinite(density).all() and density.shape == (500,)
    cells = voxel_cells(bad)
    lone = torch.bincount(cells)[cells[:: 7]]
    assert lone.tolist() == [1] * len(lone)  # a non-finite centre is alone in its voxel
    cam = look_at((4.0, 0.0, 0.0))
    near = nearness(bad, cam)
    assert torch.isfinite(near).all() and bool((near[::7] == 0).all())
    behind = nearness(torch.tensor([[10.0, 0.0, 0.0]]), cam)  # behind the camera: never "near"
    assert behind.tolist() == [0.0]
    d = guided_dropout_opacities(torch.full((500,), 0.5), 0.2, 0.85 * density + 0.15 * near, torch.Generator())
    assert torch.isfinite(d).all()
    assert neighbourhood_density(torch.zeros(1, 3)).tolist() == [0.5]
    with pytest.raises(GsgsError, match="guide must be one of"):
        from gsgs_engine.train.techniques.dropout import GaussianDropout
        GaussianDropout(guide="depth")


# -- opacity decay ----------------------------------------------------------------------------
def test_decay_logits_match_the_factor_and_stay_finite():
    from gsgs_engine.train.techniques.opacity_decay import decay_opacity_logits

    x = torch.tensor([-80.0, -5.0, 0.0, 3.0, 40.0, 200.0])
    y = decay_opacity_logits(x, 0.995)
    assert torch.isfinite(y).all()
    assert torch.allclose(torch.sigmoid(y), 0.995 * torch.sigmoid(x), rtol=1e-5, atol=0)


def test_decay_scales_opacities_and_no_reset_happens():
    from gsgs_engine.train.techniques.opacity_decay import OpacityDecay

    scene = make_scene()
    scene.background = (0.0, 0.0, 0.0)  # no white-background reset at the start of densification
    trainer = make_trainer(scene, iters=120, densify=True)
    trainer.setup()
    decay = trainer.add_technique(OpacityDecay(start=1))
    assert trainer.schedule.densify_until == 120
    assert not any(trainer.schedule.is_opacity_reset_step(s) for s in range(1, 121))
    before = trainer.model.opacities.detach().clone()
    decay.after_step(trainer, 1)
    assert torch.allclose(trainer.model.opacities.detach(), 0.995 * before, rtol=1e-5)
    trainer.train()
    assert trainer.opacity_resets == 0 and trainer.nan_steps_skipped == 0
    assert decay.steps_decayed == 121  # 120 steps plus the call above
    assert trainer.densify_log[-1]["step"] == 100  # densified to the end (3DGS's schedule stops at step 60)


def test_decay_keeps_or_drops_the_white_backgrounds_first_reset():
    from gsgs_engine import GsgsError
    from gsgs_engine.train.techniques.opacity_decay import OpacityDecay

    resets = {}
    for white_reset in (1, 0):
        scene = make_scene()
        scene.background = (1.0, 1.0, 1.0)  # white: 3DGS resets the opacities once, at the start of densification
        trainer = make_trainer(scene, iters=100, densify=True)
        trainer.setup()
        decay = trainer.add_technique(OpacityDecay(white_reset=white_reset))
        start = trainer.schedule.densify_from  # step 2 of 100
        assert start > 1 and trainer.schedule.white_reset_step(start) is bool(white_reset)
        assert not any(trainer.schedule.white_reset_step(s) for s in range(1, 101) if s != start)
        seen = []
        trainer.add_technique(Probe(after=lambda t, step: seen.append(float(t.model.opacities.detach().max()))))
        trainer.train(until=start)
        resets[white_reset] = seen[start - 1]  # the largest opacity right after the start of densification
        assert ("keep the one" in decay.report()["opacity_reset"]) is bool(white_reset)
    assert resets[1] <= 0.01 + 1e-6 < resets[0]  # the reset caps every opacity at 0.01; without it none is capped
    with pytest.raises(GsgsError, match="white_reset"):
        OpacityDecay(white_reset=2)


# -- binocular --------------------------------------------------------------------------------
def _plane_pair(baseline: float):
    """A textured fronto-parallel plane at depth 5 seen by a camera and its x-shifted twin."""
    from gsgs_engine.train.techniques.binocular import shifted_camera

    size = 48
    cam = look_at((0.0, -5.0, 0.0), target=(0.0, 0.0, 0.0), size=size)
    shifted = shifted_camera(cam, baseline)
    # the plane y = 0: its texture as a function of world x, z; each camera sees it at z-depth 5
    from gsgs_engine.priors.warp import unproject

    def image_of(c):
        pts = unproject(c, torch.full((size, size), 5.0, dtype=torch.float64))
        x, z = pts[..., 0], pts[..., 2]
        return torch.stack([0.5 + 0.4 * torch.sin(3 * x), 0.5 + 0.4 * torch.cos(2 * z),
                            0.5 + 0.2 * torch.sin(x + z)], dim=-1).float()

    return cam, shifted, image_of(cam), image_of(shifted), torch.full((size, size), 5.0)


def test_binocular_warp_with_true_depth_reproduces_the_view():
    from gsgs_engine.train.techniques.binocular import masked_l1, warp_shifted_to_view

    cam, shifted, img, img_shifted, depth = _plane_pair(0.4)
    warped, valid = warp_shifted_to_view(cam, depth, shifted, img_shifted)
    assert 0.6 < valid.float().mean() < 1.0  # the strip the shift uncovers is masked out
    assert (warped - img)[valid].abs().max() < 0.02  # bilinear resampling of a smooth texture
    assert masked_l1(warped, img, valid) < 2e-3
    wrong, valid_w = warp_shifted_to_view(cam, depth * 0.7, shifted, img_shifted)
    assert masked_l1(wrong, img, valid_w) > 5 * masked_l1(warped, img, valid)  # wrong depth costs


@pytest.mark.parametrize("scale", [1.0, 0.5])
def test_binocular_disparity_warp_equals_the_general_reprojection(scale):
    """The shifted view's warp as a disparity along x gives what priors.warp.backward_warp's reprojection through
    world space gives: the same samples, the same valid pixels and the same depth gradient (a full-size and a
    half-size shifted render; depths with holes, a non-finite and a negative value)."""
    from gsgs_engine.priors.warp import backward_warp
    from gsgs_engine.train.techniques.binocular import shifted_camera, warp_shifted_to_view

    g = torch.Generator().manual_seed(3)
    cam = look_at((0.3, -4.0, 0.5), target=(0.0, 0.0, 0.2), size=40)
    shifted = shifted_camera(cam, -0.35)
    if scale != 1.0:
        shifted = shifted.scaled(scale)
    image = torch.rand(shifted.height, shifted.width, 3, generator=g)
    depth = 3.0 + 2.0 * torch.rand(40, 40, generator=g)
    depth[5, 5], depth[6, 7], depth[8, 9] = 0.0, float("nan"), -1.0
    d1 = depth.clone().requires_grad_()
    d2 = depth.clone().requires_grad_()
    fast, valid_fast = warp_shifted_to_view(cam, d1, shifted, image)
    slow, valid_slow = backward_warp(cam, d2, shifted, image)
    assert torch.equal(valid_fast, valid_slow) and 0.5 < valid_fast.float().mean() < 1.0
    torch.testing.assert_close(fast[valid_fast], slow[valid_slow], atol=1e-5, rtol=0)
    weights = torch.rand(40, 40, 3, generator=g) * valid_fast[..., None]
    (fast * weights).sum().backward()
    (slow * weights).sum().backward()
    ok = valid_fast & torch.isfinite(depth)
    torch.testing.assert_close(d1.grad[ok], d2.grad[ok], atol=1e-4, rtol=1e-3)
    assert torch.isfinite(d1.grad).all()


def test_binocular_baseline_is_a_tenth_of_the_depth_capped_by_the_rig():
    from gsgs_engine import GsgsError
    from gsgs_engine.train.techniques.binocular import BinocularConsistency, rig_baseline, scene_depth

    # a forward-facing rig: cameras 0.2 apart before a wall at depth 10 (a tenth of it: 1.0 > 0.75 x 0.2)
    cams = [np.array([x, 0.0, 0.0]) for x in (-0.2, 0.0, 0.2)]
    wall = np.stack([np.linspace(-5, 5, 800), np.zeros(800), np.full(800, 10.0)], 1)
    assert 10.0 <= scene_depth(wall, cams) < 11.2
    assert rig_baseline(cams) == pytest.approx(0.2) and rig_baseline(cams[:1]) is None
    trainer = make_trainer(iters=10)
    trainer.setup()
    bino = trainer.add_technique(BinocularConsistency())
    means = trainer.model.means.detach().numpy()
    centres = [v.camera.center for v in trainer.train_views]
    depth_rule, cap = 0.1 * scene_depth(means, centres), 0.75 * rig_baseline(centres)
    assert bino.max_baseline == pytest.approx(min(depth_rule, cap))
    assert bino.report()["rig_baseline"] == pytest.approx(rig_baseline(centres))
    # the rule that binds, either way round
    loose, tight = BinocularConsistency(rig_fraction=1e6), BinocularConsistency(rig_fraction=1e-3)
    loose.install(trainer)
    tight.install(trainer)
    assert loose.max_baseline == pytest.approx(depth_rule)
    assert tight.max_baseline == pytest.approx(1e-3 * rig_baseline(centres))
    restored = BinocularConsistency()
    restored.load_state_dict(tight.state_dict())
    assert restored.max_baseline == tight.max_baseline and restored.rig_baseline == tight.rig_baseline
    with pytest.raises(GsgsError, match="rig_fraction"):
        BinocularConsistency(rig_fraction=0)


@pytest.mark.parametrize("scale", [1.0, 0.5])  # 0.5: the shifted view rendered at half size (issue 29)
def test_binocular_terms_have_finite_gradients_and_smoothness_respects_edges(scale):
    from gsgs_engine.train.techniques.binocular import BinocularConsistency, edge_aware_smoothness

    trainer = make_trainer(iters=10)
    trainer.setup()
    bino = trainer.add_technique(BinocularConsistency(start_fraction=0.0, scale=scale))
    assert bino.report()["scale"] == scale
    ctx = ctx_for(trainer, 5)
    cam = trainer.train_views[0].camera
    ctx.render = trainer.render_for_training(ctx, cam)
    terms = bino.loss_terms(ctx)
    assert set(terms) == {"binocular_l1", "binocular_smooth"}
    loss = sum(w * v for w, v in terms.values())
    assert torch.isfinite(loss) and loss > 0
    loss.backward()
    for name, p in trainer.model.params.items():
        assert p.grad is None or torch.isfinite(p.grad).all(), name
    assert trainer.model.params["means"].grad.abs().sum() > 0
    # a disparity step on an image edge costs less than the same step in a flat region
    disp = torch.zeros(16, 16)
    disp[:, 8:] = 1.0
    edge = torch.zeros(16, 16, 3)
    edge[:, 8:] = 1.0
    on_edge, flat = edge_aware_smoothness(disp, edge), edge_aware_smoothness(disp, torch.zeros(16, 16, 3))
    assert flat > 0 and on_edge / flat == pytest.approx(float(np.exp(-0.5)), rel=1e-5)  # |dI/dx| = 0.5 there


def test_binocular_bands_partition_the_rows_and_crop_the_camera_exactly():
    from gsgs_engine.render import render
    from gsgs_engine.train.techniques.binocular import band_camera, band_rows

    for height, bands in ((378, 2), (400, 3), (48, 2), (20, 3), (7, 2)):
        edges = [band_rows(height, bands, i) for i in range(bands)]
        assert edges[0][0] == 0 and edges[-1][1] == height
        assert all(a[1] == b[0] for a, b in zip(edges, edges[1:])) and all(y1 > y0 for y0, y1 in edges)
        if height >= 16 * bands:
            assert all(y0 % 16 == 0 for y0, _ in edges)  # on the rasteriser's tile rows
    # a band camera sees the rows of the full view (the same rays): equal away from the band's inner edge, where
    # Gaussians centred beyond it meet the projection's frustum clamp at the band's edge instead of the image's
    trainer = make_trainer(iters=10)
    trainer.setup()
    cam = trainer.train_views[0].camera
    m = trainer.model
    with torch.no_grad():
        full = render(m.means, m.quats, m.scales, m.opacities, m.sh(0), cam, sh_degree=0, background=torch.ones(3))
        for index, far_rows in ((0, slice(0, 8)), (1, slice(8, None))):
            y0, y1 = band_rows(cam.height, 2, index)
            band = render(m.means, m.quats, m.scales, m.opacities, m.sh(0), band_camera(cam, y0, y1), sh_degree=0,
                          background=torch.ones(3))
            assert band.color.shape == (y1 - y0, cam.width, 3)
            torch.testing.assert_close(band.color[far_rows], full.color[y0:y1][far_rows], atol=1e-5, rtol=0)
            torch.testing.assert_close(band.color, full.color[y0:y1], atol=1e-2, rtol=0)


def test_binocular_bands_give_finite_terms_on_every_band():
    from gsgs_engine import GsgsError
    from gsgs_engine.train.techniques.binocular import BinocularConsistency

    trainer = make_trainer(iters=10)
    trainer.setup()
    bino = trainer.add_technique(BinocularConsistency(start_fraction=0.0, bands=2))
    assert bino.report()["bands"] == 2
    cam = trainer.train_views[0].camera
    for step in range(1, 7):  # the band is drawn at random: both come up
        ctx = ctx_for(trainer, step)
        ctx.render = trainer.render_for_training(ctx, cam)
        terms = bino.loss_terms(ctx)
        loss = sum(w * v for w, v in terms.values())
        assert torch.isfinite(loss) and loss > 0
        loss.backward()
        assert torch.isfinite(trainer.model.params["means"].grad).all()
        trainer.model.params["means"].grad = None
    with pytest.raises(GsgsError, match="bands"):
        BinocularConsistency(bands=0)


# -- count control ----------------------------------------------------------------------------
def test_count_control_cap_is_respected_and_lowers_the_threshold_when_few():
    from gsgs_engine.train.techniques.count_control import GaussianBudget, threshold_scale

    assert threshold_scale(10, 1000, 0.5, 0.25) == 0.25
    assert threshold_scale(250, 1000, 0.5, 0.25) == 0.5
    assert threshold_scale(600, 1000, 0.5, 0.25) == 1.0
    trainer = make_trainer(iters=120, densify=True)
    trainer.config.densify_config.max_gaussians = 100_000
    trainer.config.densify_config.grad_threshold = 1e-7  # every Gaussian wants to densify
    trainer.setup()
    n0 = trainer.model.num_gaussians
    budget = trainer.add_technique(GaussianBudget(per_pixel=(n0 + 60) / (3 * 32 * 32)))
    assert budget.budget == max(1000, n0 + 60) and trainer.config.densify_config.max_gaussians == budget.budget
    trainer.train()
    assert max(e["num_gaussians"] for e in trainer.densify_log) <= budget.budget


def test_absgrad_feeds_densification_the_absolute_statistic_with_a_raised_threshold(monkeypatch):
    from gsgs_engine.render import cpu_backend
    from gsgs_engine.train.densify import DensifyStats
    from gsgs_engine.train.techniques.absgrad import AbsoluteGradients
    from gsgs_engine.train.techniques.count_control import GaussianBudget

    if not cpu_backend.available():
        pytest.skip(f"compiled CPU rasteriser unavailable: {cpu_backend.unavailable_reason()}")
    with pytest.raises(GsgsError, match="threshold"):
        AbsoluteGradients(threshold=0)
    trainer = make_trainer(iters=30, densify=True)
    trainer.config.backend = "cpu"
    trainer.setup()
    base = trainer.config.densify_config.grad_threshold
    absgrad = trainer.add_technique(AbsoluteGradients(threshold=3.0))
    budget = trainer.add_technique(GaussianBudget())
    assert trainer.config.densify_config.gradient == "abs"
    assert trainer.config.densify_config.grad_threshold == pytest.approx(3.0 * base)
    assert budget.base_threshold == pytest.approx(3.0 * base)  # the count control lowers from the raised base
    fed = []
    plain = DensifyStats.accumulate

    def spy(self, grad, radii, width, height):
        r, _ = trainer.last_step_renders[0]
        fed.append((grad is r.means2d.absgrad, bool((grad >= r.means2d.grad.abs() * (1 - 1e-5) - 1e-7).all())))
        return plain(self, grad, radii, width, height)

    monkeypatch.setattr(DensifyStats, "accumulate", spy)
    trainer.train(until=5)
    assert fed and all(same and above for same, above in fed)
    assert absgrad.report()["grad_threshold"] == pytest.approx(3.0 * base)


def test_clone_split_boundary_decides_which_gaussians_are_split():
    from gsgs_engine.train.densify import DensifyConfig, DensifyStats, clone_and_split_rows
    from gsgs_engine.train.techniques.clone_split import CloneSplitBoundary

    for bad in (0, 1, -0.1):
        with pytest.raises(GsgsError, match="boundary"):
            CloneSplitBoundary(boundary=bad)
    trainer = make_trainer(iters=30, densify=True)
    trainer.setup()
    technique = trainer.add_technique(CloneSplitBoundary(boundary=0.004))
    assert trainer.config.densify_config.percent_dense == 0.004
    assert technique.report()["boundary"] == 0.004 and technique.report()["default_boundary"] == 0.01
    # Gaussians at 0.002 / 0.007 / 0.02 of the extent, all above the gradient threshold: 3DGS's 0.01 clones the
    # first two and splits the third; the boundary at 0.004 splits the middle one too
    model = trainer.model
    with torch.no_grad():
        keep = torch.zeros(model.num_gaussians, dtype=torch.bool)
        keep[:3] = True
        from gsgs_engine.train.densify import keep_gaussians

        keep_gaussians(model, trainer.optimizer, keep)
        model.params["log_scales"][:] = torch.log(torch.tensor([[0.002], [0.007], [0.02]])).expand(3, 3)
    stats = DensifyStats(3)
    stats.grad_accum[:] = 1.0
    stats.denom[:] = 1.0
    for boundary, cloned, split in ((0.01, [True, True, False], [False, False, True]),
                                    (0.004, [True, False, False], [False, True, True])):
        _, clone_mask, split_mask = clone_and_split_rows(model, stats, 1.0, DensifyConfig(percent_dense=boundary))
        assert clone_mask.tolist() == cloned and split_mask.tolist() == split


def test_absgrad_on_the_reference_rasteriser_keeps_the_plain_statistic_and_says_so():
    from gsgs_engine.train.techniques.absgrad import AbsoluteGradients

    logged = []
    trainer = make_trainer(iters=4, densify=True)
    trainer.config.backend = "reference"
    trainer.log = logged.append
    trainer.setup()
    base = trainer.config.densify_config.grad_threshold
    absgrad = trainer.add_technique(AbsoluteGradients())
    assert trainer.config.densify_config.gradient == "sum" and trainer.config.densify_config.grad_threshold == base
    trainer.train()  # no render asks the reference rasteriser for it
    assert trainer.step == 4 and any("absgrad" in m and "plain gradient" in m for m in logged)
    assert absgrad.report()["statistic"].startswith("off:")


# -- resume, the switch, the trainer untouched ------------------------------------------------
ALL = "count_control,dropout,binocular:start_fraction=0.3,opacity_decay"


def _run(tmp_path, until=None, resume=False, max_gaussians=None, techniques=ALL):
    from gsgs_engine.train.techniques.catalogue import make_techniques, parse_techniques

    trainer = make_trainer(iters=40, densify=True, checkpoint_every=20, tmp_path=tmp_path)
    if max_gaussians is not None:
        trainer.config.densify_config.max_gaussians = max_gaussians
    trainer.setup(resume=resume)
    for t in make_techniques(parse_techniques(techniques)):
        trainer.add_technique(t)
    trainer.train(until=until)
    return trainer


@pytest.mark.parametrize("guide", ["density", "anchor"])
def test_resume_with_guided_dropout_is_bit_identical(tmp_path, guide):
    spec = ALL.replace("dropout", f"dropout:guide={guide}")
    straight = _run(tmp_path / "a", techniques=spec)
    _run(tmp_path / "b", until=20, techniques=spec)
    resumed = _run(tmp_path / "b", resume=True, techniques=spec)
    assert resumed.step == straight.step == 40
    for name, p in straight.model.params.items():
        assert torch.equal(p, resumed.model.params[name]), name
    uniform = _run(tmp_path / "c")
    assert not torch.equal(uniform.model.params["means"], straight.model.params["means"])
    assert straight.techniques[1].report()["guide"] == guide


# 100_000: above the count control's budget (1000 here), which then lowers the cap at install: the checkpoint must
# record the settings as asked, or the resume is refused as "trained with other settings" (found on a cancelled
# LLFF protocol cell)
@pytest.mark.parametrize("max_gaussians,techniques", [(None, ALL), (100_000, ALL), (None, "smoothing," + ALL),
                                                       (None, "absgrad," + ALL), (None, "clone_split," + ALL)])
def test_resume_with_techniques_is_bit_identical(tmp_path, max_gaussians, techniques):
    straight = _run(tmp_path / "a", max_gaussians=max_gaussians, techniques=techniques)
    interrupted = _run(tmp_path / "b", until=20, max_gaussians=max_gaussians, techniques=techniques)
    if max_gaussians is not None:
        assert interrupted.config.densify_config.max_gaussians < max_gaussians  # the budget took over
    resumed = _run(tmp_path / "b", resume=True, max_gaussians=max_gaussians, techniques=techniques)
    assert resumed.step == straight.step == 40
    for name, p in straight.model.params.items():
        assert torch.equal(p, resumed.model.params[name]), name
    assert {t.name: t.report() for t in straight.techniques} == {t.name: t.report() for t in resumed.techniques}


def test_switch_validates_names_and_options():
    from gsgs_engine.train.techniques.catalogue import make_techniques, parse_techniques

    parsed = parse_techniques("opacity_decay:factor=0.99, dropout")
    assert [p["name"] for p in parsed] == ["dropout", "opacity_decay"]  # catalogue order
    assert parsed[1]["options"] == {"factor": 0.99}
    assert parse_techniques("none") == [] and parse_techniques(None) == []
    with pytest.raises(GsgsError, match="unknown technique 'drop'.*dropout"):
        parse_techniques("drop")
    with pytest.raises(GsgsError, match="no option 'rate=0.3'.*max_rate"):
        parse_techniques("dropout:rate=0.3")
    with pytest.raises(GsgsError, match="named twice"):
        parse_techniques(["dropout", "dropout"])
    with pytest.raises(GsgsError, match="factor must be in"):
        make_techniques(parse_techniques("opacity_decay:factor=1.5"))


def test_gsgs_train_records_the_techniques(tmp_path, capsys):
    import json

    from gsgs_engine.cli import main
    from test_train_cli import write_tiny_blender_scene

    scene = write_tiny_blender_scene(tmp_path / "scene")
    out = tmp_path / "run"
    assert main(["train", str(scene), "--out", str(out), "--iters", "8", "--sh-degree", "0", "--init-points", "200",
                 "--techniques", "opacity_decay:factor=0.99,dropout"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["plan"]["techniques"] == [{"name": "dropout", "options": {}},
                                             {"name": "opacity_decay", "options": {"factor": 0.99}}]
    assert set(metrics["techniques"]) == {"dropout", "opacity_decay"}
    assert metrics["techniques"]["opacity_decay"]["factor"] == 0.99
    assert metrics["plan"]["schedule"]["densify_until"] == 8  # the decay's schedule is what ran
    assert main(["train", str(scene), "--out", str(tmp_path / "bad"), "--techniques", "dropuot"]) == 2
    assert "unknown technique 'dropuot'" in capsys.readouterr().err


def test_job_settings_and_cli_carry_the_techniques():
    from gsgs_engine.priors.config import prior_config_from_settings
    from gsgs_engine.reconstruct import config_from_settings

    config_from_settings({"techniques": ["dropout"]})  # a known job setting
    assert prior_config_from_settings({"techniques": "dropout,opacity_decay"}).techniques == ["dropout",
                                                                                               "opacity_decay"]
    with pytest.raises(GsgsError, match="settings.techniques"):
        prior_config_from_settings({"techniques": 3})


def test_trainer_names_none_of_these_techniques():
    """Issue 13's acceptance: a technique touches its module and its registration, not the trainer."""
    source = (REPO / "gsgs_engine/train/trainer.py").read_text()
    for name in ("dropout", "opacity_decay", "binocular", "count_control", "catalogue"):
        assert name not in source


# -- the 3D smoothing filter --------------------------------------------------------------------
def test_smoothing_keeps_large_gaussians_and_bounds_fine_ones():
    from gsgs_engine.train.techniques.smoothing import smoothed

    scales = torch.tensor([[1.0, 1.0, 1.0], [1e-3, 2.0, 2.0], [0.0, 0.0, 0.0]])
    opac = torch.tensor([0.8, 0.8, 0.8])
    var = torch.full((3,), 0.01)  # std 0.1
    s, o = smoothed(scales, opac, var)
    assert torch.allclose(s[0], torch.full((3,), (1.01) ** 0.5)) and o[0] == pytest.approx(0.8 / 1.01 ** 1.5, rel=1e-5)
    assert s[1, 0] == pytest.approx(0.1, rel=1e-3), "a needle is as thick as the filter"
    assert o[1] == pytest.approx(0.8 * 1e-3 / float(s[1, 0]) * (4 / 4.01), rel=1e-3), "its integral is kept"
    assert torch.equal(o[2], torch.tensor(0.0)) and torch.all(s[2] > 0), "a vanished Gaussian stays finite, unseen"
    unfiltered = smoothed(scales[:2], opac[:2], torch.zeros(2))
    assert torch.equal(unfiltered[0], scales[:2]) and torch.equal(unfiltered[1], opac[:2]), "zero variance: no filter"


def test_smoothing_gradients_are_finite_for_degenerate_scales():
    from gsgs_engine.train.techniques.smoothing import smoothed

    log_scales = torch.tensor([[-200.0, 0.0, 0.0], [-5.0, -5.0, -5.0], [3.0, 3.0, -80.0]], requires_grad=True)
    logits = torch.zeros(3, requires_grad=True)
    s, o = smoothed(torch.exp(log_scales), torch.sigmoid(logits), torch.full((3,), 1e-4))
    (s.sum() + o.sum()).backward()
    assert torch.isfinite(s).all() and torch.isfinite(o).all()
    assert torch.isfinite(log_scales.grad).all() and torch.isfinite(logits.grad).all()


def test_pixel_footprints_take_the_finest_camera_that_sees_a_centre():
    from gsgs_engine.cameras import Camera
    from gsgs_engine.train.techniques.smoothing import pixel_footprints

    near = Camera(R=np.eye(3), t=np.array([0.0, 0.0, 2.0]), fx=100.0, fy=100.0, cx=50.0, cy=50.0, width=100, height=100)
    far = Camera(R=np.eye(3), t=np.array([0.0, 0.0, 8.0]), fx=200.0, fy=100.0, cx=50.0, cy=50.0, width=100, height=100)
    means = torch.tensor([[0.0, 0.0, 0.0],  # both see it: near 2/100, far 8/200
                          [1.5, 0.0, 0.0],  # outside the near camera's widened image (u = 125 > 115), inside far's
                          [0.0, 0.0, -9.0],  # behind both
                          [float("nan"), 0.0, 0.0]])
    f = pixel_footprints(means, [near, far])
    assert f[0] == pytest.approx(0.02) and f[1] == pytest.approx(0.04)
    assert f[2] == pytest.approx(0.04) and f[3] == pytest.approx(0.04), "unseen centres get the coarsest footprint"
    assert torch.equal(pixel_footprints(means[2:3], [near]), torch.zeros(1)), "nothing seen: no filter"


def test_smoothing_filters_training_renders_and_bakes_at_the_last_step():
    from gsgs_engine.train.techniques.catalogue import make_techniques, parse_techniques

    trainer = make_trainer(iters=6)
    trainer.setup()
    (smoothing,) = [trainer.add_technique(t) for t in make_techniques(parse_techniques("smoothing:variance=50"))]
    cam = trainer.train_views[0].camera
    with torch.no_grad():
        plain = trainer.render(cam).color.clone()
        filtered = trainer.render_for_training(ctx_for(trainer, 1), cam).color
    assert not torch.allclose(filtered, plain, atol=1e-4), "a training render sees the filtered Gaussians"
    trainer.train()
    assert smoothing.baked_at == 6
    with torch.no_grad():
        after = trainer.render(cam).color
        training = trainer.render_for_training(ctx_for(trainer, 7), cam).color
    assert torch.equal(after, training), "after baking the model is the filtered one: no second filter"
    assert all(torch.isfinite(p).all() for p in trainer.model.params.values())
    assert smoothing.report()["baked_at_step"] == 6


def test_train_help_names_every_technique_of_the_catalogue():
    import argparse

    from gsgs_engine.priors.config import add_prior_arguments
    from gsgs_engine.train.techniques.catalogue import TECHNIQUES

    parser = argparse.ArgumentParser()
    add_prior_arguments(parser)
    text = next(a.help for a in parser._actions if a.dest == "techniques")
    assert all(name in text for name in TECHNIQUES), text
