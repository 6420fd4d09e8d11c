"""4D training: the trainer that a scene with time gets, init across time, time-aware densification,
checkpoints, pseudo views at (pose, time), and the dynamic bench on a tiny synthetic clip."""

from __future__ import annotations

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest
import torch

from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera, look_at, nerf_c2w_from_camera
from gsgs_engine.gaussians import GaussianModel
from gsgs_engine.io.dynamic import load_dynamic_scene
from gsgs_engine.spacetime import SpacetimeModel, render_at
from gsgs_engine.train.densify import DensifyConfig, DensifyStats
from gsgs_engine.train.dynamic import (SpacetimeTrainer, densify_and_prune_4d, initialise_spacetime, make_trainer,
                                       peak_opacity_in_clip, spacetime_pseudo_views)
from gsgs_engine.train.techniques.pseudo_views import PseudoSupervision, PseudoView
from gsgs_engine.train.trainer import TrainConfig, Trainer
from test_trainer import Probe

SIZE = 16


def _ring(n):
    cams = []
    for i in range(n):
        a = 2 * np.pi * i / n
        R, t = look_at((3 * np.cos(a), 3 * np.sin(a), 1.0), (0, 0, 0))
        cams.append(Camera(R=R, t=t, fx=16.0, fy=16.0, cx=SIZE / 2, cy=SIZE / 2, width=SIZE, height=SIZE))
    return cams


def _ground_truth() -> SpacetimeModel:
    """Two coloured blobs: one static, one moving along x over the clip."""
    base = GaussianModel.from_points(np.array([[0.0, 0.0, -0.3], [-0.4, 0.0, 0.3]]), np.array([[0.9, 0.1, 0.1],
                                                                                              [0.1, 0.2, 0.9]]), 0)
    with torch.no_grad():
        base.params["log_scales"].fill_(np.log(0.3))
        base.params["opacity_logits"].fill_(3.0)
    m = SpacetimeModel.from_static(base, [0.5, 0.0], [100.0, 100.0])
    with torch.no_grad():
        m.params["motion"][1, 0, 0] = 0.8  # 0.8 units per unit time along x
    return m


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """NeRF JSON with time: 5 cameras x 3 frames rendered from the ground-truth 4D model."""
    root = tmp_path_factory.mktemp("clip")
    (root / "frames").mkdir()
    gt, frames = _ground_truth(), []
    for f, t in enumerate([0.0, 0.5, 1.0]):
        for c, cam in enumerate(_ring(5)):
            with torch.no_grad():
                img = render_at(gt, replace(cam, time=t), torch.ones(3), backend="reference").color.numpy()
            stem = f"frames/c{c}_f{f}"
            cv2.imwrite(str(root / f"{stem}.png"), cv2.cvtColor((img * 255 + 0.5).astype(np.uint8), cv2.COLOR_RGB2BGR))
            frames.append({"file_path": f"./{stem}", "transform_matrix": nerf_c2w_from_camera(cam).tolist(),
                           "camera_id": c, "time": t})
    (root / "transforms.json").write_text(json.dumps({"fl_x": 16.0, "fl_y": 16.0, "cx": SIZE / 2, "cy": SIZE / 2,
                                                      "w": SIZE, "h": SIZE, "frames": frames}))
    return root


def _config(**kw):
    base = dict(iters=30, sh_degree=0, init="random", random_init_points=60, checkpoint_every=0)
    base.update(kw)
    return TrainConfig(**base)


def _strip_time(scene):
    for v in scene.views:
        v.camera = replace(v.camera, time=None)
    return scene


def test_a_4d_model_exists_only_when_the_data_has_time(clip):
    scene = load_dynamic_scene(clip, train_cameras=2)
    trainer = make_trainer(scene, _config())
    assert isinstance(trainer, SpacetimeTrainer)
    trainer.setup()
    assert isinstance(trainer.model, SpacetimeModel)
    assert {g["name"] for g in trainer.optimizer.param_groups} >= {"t_center", "t_log_scale", "motion", "omega"}

    static = _strip_time(load_dynamic_scene(clip, train_cameras=2))
    trainer = make_trainer(static, _config())
    assert type(trainer) is Trainer
    trainer.setup()
    assert type(trainer.model) is GaussianModel and "t_center" not in trainer.model.params
    assert trainer.model.to_ply().extra == {}
    with pytest.raises(GsgsError, match="carry no time"):
        SpacetimeTrainer(static, _config())


def test_random_init_spreads_gaussians_over_time(clip):
    scene = load_dynamic_scene(clip, train_cameras=2)
    model, info = initialise_spacetime(scene, scene.train, _config(random_init_points=400),
                                       torch.Generator().manual_seed(0))
    assert info.method == "random" and model.num_gaussians == 400
    tc = model.t_center.detach()
    assert float(tc.min()) >= 0 and float(tc.max()) <= 1 and 0.4 < float(tc.mean()) < 0.6


def test_init_from_points_triangulated_per_frame(clip, monkeypatch):
    import gsgs_engine.sfm as sfm

    calls = []

    def fake_triangulate(views):
        t = views[0].camera.time
        assert all(v.camera.time == t for v in views)  # one frame at a time
        calls.append(t)
        pts = np.random.default_rng(len(calls)).normal(size=(50, 3))
        return pts, np.full((50, 3), 0.5)

    monkeypatch.setattr(sfm, "triangulate_known_poses", fake_triangulate)
    scene = load_dynamic_scene(clip, train_cameras=2)
    model, info = initialise_spacetime(scene, scene.train, _config(init="auto"), torch.Generator())
    assert calls == [0.0, 0.5, 1.0] and info.method == "sfm" and model.num_gaussians == 150
    assert sorted(set(model.t_center.detach().tolist())) == [0.0, 0.5, 1.0]
    assert torch.allclose(model.t_scale, torch.full((150,), 1.0))  # two frame spacings of 0.5


def _trainer_with_model(clip, model):
    scene = load_dynamic_scene(clip, train_cameras=2)
    trainer = SpacetimeTrainer(scene, _config())
    trainer.setup(initial_model=model)
    return trainer


def test_densify_clones_and_splits_carry_temporal_params(clip):
    base = GaussianModel.from_points(np.array([[0.0, 0, 0], [0.5, 0, 0], [0, 0.5, 0]]), None, 0)
    with torch.no_grad():
        base.params["log_scales"].copy_(torch.log(torch.tensor([[0.001] * 3, [0.5] * 3, [0.5] * 3])))
        base.params["opacity_logits"].fill_(2.0)
    model = SpacetimeModel.from_static(base, [0.2, 0.6, 0.9], [0.3, 0.4, 0.5])
    with torch.no_grad():
        model.params["motion"].copy_(torch.arange(27.0).reshape(3, 3, 3))
        model.params["omega"].copy_(torch.arange(12.0).reshape(3, 4))
    trainer = _trainer_with_model(clip, model)
    # give every parameter some Adam state, as after real steps
    for p in trainer.model.params.values():
        p.grad = torch.ones_like(p)
    trainer.optimizer.step()
    p0 = {k: v.detach().clone() for k, v in trainer.model.params.items()}
    stats = DensifyStats(3)
    stats.grad_accum[:] = torch.tensor([1.0, 1.0, 0.0])
    stats.denom[:] = 1
    info = densify_and_prune_4d(trainer.model, trainer.optimizer, stats, 1.0, DensifyConfig(), prune_large=False,
                                generator=torch.Generator().manual_seed(0))
    m = trainer.model
    assert (info["cloned"], info["split"]) == (1, 1)
    # kept: 0 (cloned parent), 2 (no gradient); appended: clone of 0, two children of 1 (parent 1 removed)
    assert m.num_gaussians == 5
    rows = [0, 2, 0, 1, 1]
    for name in ("t_center", "t_log_scale", "motion", "omega", "sh_dc", "quats"):
        assert torch.equal(m.params[name].detach(), p0[name][rows]), name
    # split children: new centres around the parent, smaller; the clone is an exact copy
    assert torch.equal(m.params["means"].detach()[2], p0["means"][0])
    assert not torch.equal(m.params["means"].detach()[3], p0["means"][1])
    assert bool((m.params["log_scales"].detach()[3:] < p0["log_scales"][1]).all())
    for group in trainer.optimizer.param_groups:
        p = group["params"][0]
        assert p is m.params[group["name"]] and p.shape[0] == 5
        state = trainer.optimizer.state[p]
        assert state["exp_avg"].shape == p.shape
        assert float(state["exp_avg"][2:].abs().sum()) == 0  # appended rows start with zero moments
        if p[0].numel():  # (sh_rest is empty at degree 0)
            assert float(state["exp_avg"][:2].abs().sum()) > 0  # kept rows keep theirs


def test_prune_uses_peak_opacity_within_the_clip(clip):
    base = GaussianModel.from_points(np.array([[0.0, 0, 0], [0.3, 0, 0], [0, 0.3, 0]]), None, 0)
    with torch.no_grad():
        base.params["opacity_logits"].fill_(2.0)
    # visible all clip / centred after the clip but wide / centred long after the clip and short-lived
    model = SpacetimeModel.from_static(base, [0.5, 1.2, 3.0], [0.1, 1.0, 0.1])
    peak = peak_opacity_in_clip(model)
    s = torch.sigmoid(torch.tensor(2.0))
    assert torch.allclose(peak, torch.stack([s, s * np.exp(-0.04), s * np.exp(-400.0)]))
    trainer = _trainer_with_model(clip, model)
    info = densify_and_prune_4d(trainer.model, trainer.optimizer, DensifyStats(3, device=trainer.device), 1.0,
                                DensifyConfig(), prune_large=False)
    assert info["pruned"] == 1 and torch.allclose(trainer.model.t_center.detach().cpu(), torch.tensor([0.5, 1.2]))


def test_opacity_decay_of_a_4d_model_follows_each_gaussians_presence_at_the_step_time(clip):
    from gsgs_engine.train.techniques.opacity_decay import OpacityDecay, decay_opacity_logits, step_presence

    base = GaussianModel.from_points(np.array([[0.0, 0, 0], [0.3, 0, 0], [0, 0.3, 0], [0.3, 0.3, 0]]), None, 0)
    with torch.no_grad():
        base.params["opacity_logits"].copy_(torch.tensor([2.0, 2.0, 2.0, -30.0]))
    # centred at the step's time 0.5 / one temporal scale away / far outside / faint and centred
    model = SpacetimeModel.from_static(base, [0.5, 0.7, 3.0, 0.5], [0.1, 0.2, 0.1, 0.1])
    trainer = _trainer_with_model(clip, model)
    cam = replace(trainer.train_views[0].camera, time=0.5)
    trainer.last_step_renders = [(None, cam)]
    w = step_presence(trainer)
    assert torch.allclose(w, torch.tensor([1.0, float(np.exp(-1.0)), 0.0, 1.0]), atol=1e-6)
    before = torch.sigmoid(trainer.model.params["opacity_logits"].detach().clone())
    plain = OpacityDecay(factor=0.9, start=1)  # the default: every Gaussian by the factor
    saved = trainer.model.params["opacity_logits"].detach().clone()
    plain.after_step(trainer, 1)
    assert torch.allclose(torch.sigmoid(trainer.model.params["opacity_logits"].detach()), before * 0.9, rtol=1e-5)
    with torch.no_grad():
        trainer.model.params["opacity_logits"].copy_(saved)
    decay = trainer.add_technique(OpacityDecay(factor=0.9, start=1, presence=1))
    decay.after_step(trainer, 1)
    after = torch.sigmoid(trainer.model.params["opacity_logits"].detach())
    assert torch.isfinite(trainer.model.params["opacity_logits"]).all()
    assert torch.allclose(after, before * torch.tensor([0.9, 0.9 ** float(np.exp(-1.0)), 1.0, 0.9]), rtol=1e-5, atol=0)
    assert "4D" in decay.report()["presence"] and "off" in plain.report()["presence"]
    with pytest.raises(GsgsError, match="presence"):
        OpacityDecay(presence=2)
    # a view without a time, or a 3D model: every Gaussian decays by the factor, as the float form does
    trainer.last_step_renders = [(None, replace(cam, time=None))]
    assert step_presence(trainer) is None
    x = torch.tensor([-5.0, 0.0, 3.0])
    assert torch.equal(decay_opacity_logits(x, torch.full((3,), 0.995)), decay_opacity_logits(x, 0.995))


def test_training_steps_render_at_time_move_temporal_params_and_use_pseudo_times(clip):
    scene = load_dynamic_scene(clip, train_cameras=2)
    trainer = SpacetimeTrainer(scene, _config(iters=8))
    trainer.setup()
    before = {k: v.detach().clone() for k, v in trainer.model.params.items()}
    cam = replace(scene.test[0].camera, time=0.25)
    target = np.full((SIZE, SIZE, 3), 0.5, np.float32)
    trainer.add_technique(PseudoSupervision([PseudoView(camera=cam, image=target, weight=0.5, name="p")]))
    seen = []
    trainer.add_technique(Probe(loss=lambda ctx: seen.append((
        ctx.trainer.train_views[ctx.view_index].camera.time,
        ctx.shared["pseudo"][1].camera.time if "pseudo" in ctx.shared else None))))
    trainer.train()
    assert trainer.step == 8 and trainer.nan_steps_skipped == 0
    assert {t for t, _ in seen} <= {0.0, 0.5, 1.0} and {p for _, p in seen} == {0.25}
    assert "pseudo_l1" in trainer.last_losses
    for name in ("t_center", "t_log_scale", "motion", "omega"):
        assert not torch.equal(before[name], trainer.model.params[name].detach()), name
    with torch.no_grad():
        a = trainer.render(replace(cam, time=0.0)).color
        b = trainer.render(replace(cam, time=1.0)).color
    assert not torch.allclose(a, b)


def test_checkpoint_resume_keeps_the_4d_model(clip, tmp_path):
    scene = load_dynamic_scene(clip, train_cameras=2)
    trainer = SpacetimeTrainer(scene, _config(iters=6), checkpoint_dir=tmp_path)
    trainer.setup()
    trainer.train(until=3)
    trainer.save_checkpoint()
    again = SpacetimeTrainer(scene, _config(iters=6), checkpoint_dir=tmp_path)
    again.setup(resume=True)
    assert again.step == 3 and isinstance(again.model, SpacetimeModel)
    for name, value in trainer.model.params.items():
        assert torch.equal(again.model.params[name].detach(), value.detach()), name
    assert len(again.optimizer.param_groups) == len(trainer.optimizer.param_groups)
    again.train()
    assert again.step == 6
    # a 3D trainer cannot silently resume a 4D checkpoint into a 3D model, nor the reverse
    static = _strip_time(load_dynamic_scene(clip, train_cameras=2))
    plain = Trainer(static, _config(iters=6), checkpoint_dir=tmp_path / "s")
    plain.setup()
    plain.train(until=2)
    plain.save_checkpoint()
    with pytest.raises(GsgsError, match="3D model"):
        SpacetimeTrainer(scene, _config(iters=6), checkpoint_dir=tmp_path / "s").setup(resume=True)


def test_pseudo_views_at_pose_time_pairs_point_to_same_time_photos(clip):
    scene = load_dynamic_scene(clip, train_cameras=2)
    train = scene.train
    views = spacetime_pseudo_views(train, per_time=2, times=[0.0, 0.4, 1.0], seed=1)
    assert [round(p.camera.time, 3) for p in views] == [0.0, 0.0, 0.4, 0.4, 1.0, 1.0]
    assert len({p.name for p in views}) == 6
    for p in views:
        nearest = train[p.nearest_train]
        # the photo a warp would use was taken at the frame nearest the pseudo view's time (0.4 -> 0.5)
        assert nearest.camera.time == min((0.0, 0.5, 1.0), key=lambda t: abs(t - p.camera.time))
        centres = {tuple(np.round(v.camera.center, 6)) for v in train}
        assert tuple(np.round(p.camera.center, 6)) not in centres  # between cameras, not on one
    assert len(spacetime_pseudo_views(train, per_time=1)) == 3  # default: every training frame
    with pytest.raises(GsgsError, match="outside"):
        spacetime_pseudo_views(train, 1, times=[1.5])


@pytest.mark.slow
def test_bench_runs_all_three_variants(clip, tmp_path):
    from gsgs_engine.bench.dynamic import format_table, run_dynamic_bench

    scene = load_dynamic_scene(clip, train_cameras=2)
    results = run_dynamic_bench(scene, tmp_path, iters=12, per_frame_iters=4, init_points=80, log=lambda m: None)
    for name in ("4d", "static_all", "static_per_frame"):
        r = results[name]
        assert np.isfinite(r["psnr"]) and 0 < r["ssim"] <= 1 and r["train_seconds"] > 0
        assert len(r["per_view"]) == 3  # the held-out camera at each of the 3 frames
    assert results["static_per_frame"]["models"] == 3 and results["static_per_frame"]["iters"] == 12
    assert (tmp_path / "4d" / "point_cloud.ply").is_file()
    assert "static_per_frame" in format_table(results)


def test_gsgs_train_on_time_data_exports_a_4d_ply(tmp_path):
    """The main command picks the 4D model only because the data has time, and the PLY carries it."""
    import subprocess
    import sys

    from gsgs_engine.io.ply import read_gaussian_ply
    from test_dynamic_io import write_nerf_with_time

    write_nerf_with_time(tmp_path / "clip", n_cams=4, n_frames=3, size=16)
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "gsgs_engine", "train", str(tmp_path / "clip"), "--out", str(out),
                           "--iters", "6", "--train-views", "2", "--backend", "reference", "--init", "random",
                           "--init-points", "200", "--sh-degree", "0"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    ply = read_gaussian_ply(out / "point_cloud.ply")
    assert "t_center" in ply.extra and "motion_0" in ply.extra


def test_mvs_init_runs_the_plane_sweep_per_frame(clip):
    """--init mvs on a clip: the static init's stereo, once per frame, each frame's points at its time."""
    scene = load_dynamic_scene(clip, train_cameras=3)
    lines = []
    model, info = initialise_spacetime(scene, scene.train, _config(init="mvs"), torch.Generator(), lines.append)
    assert info.method == "mvs" and model.num_gaussians == info.num_points > 0
    assert sorted(set(model.t_center.detach().tolist())) == [0.0, 0.5, 1.0]
    assert [line.split(":")[1].strip() for line in lines] == ["frame t=0.000", "frame t=0.500", "frame t=1.000"]
    assert torch.isfinite(model.means).all()
    trainer = SpacetimeTrainer(scene, _config(init="mvs", iters=2))
    trainer.setup()  # the 4D trainer makes it itself (no longer refused)
    trainer.train()
    assert trainer.init_info.method == "mvs" and trainer.step == 2


@pytest.mark.slow  # a few seconds of stereo and six steps through the CLI
def test_prior_auto_on_a_video_runs_the_4d_recipe(clip, tmp_path):
    """--prior auto on a multi-view video: per-frame dense init, per-camera exposure and, with few cameras, dropout
    and opacity decay (effect_plan's 4D recipe)."""
    import json

    from gsgs_engine.cli import main

    assert main(["train", str(clip), "--out", str(tmp_path / "run"), "--iters", "6", "--prior", "auto"]) == 0
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["init"]["method"] == "mvs" and "per frame" in metrics["init"]["reason"]
    # a clip of a few cameras: the few-camera 4D recipe (effect_plan.AUTO_4D_FEW_TECHNIQUES)
    assert [t["name"] for t in metrics["plan"]["techniques"]] == ["dropout", "opacity_decay", "exposure"]
    from gsgs_engine.effect_plan import POSITION_LR_SCALE  # and the means moved faster than 3DGS's rate

    assert metrics["plan"]["effects"]["position_lr"]["value"] == POSITION_LR_SCALE > 1
    exposure = metrics["techniques"]["exposure"]
    assert exposure["cameras"] == len({k for k in exposure["per_camera"]}) >= 2  # one correction per camera


def test_absgrad_reaches_the_4d_densification(clip, monkeypatch):
    from gsgs_engine.render import cpu_backend
    from gsgs_engine.train.densify import DensifyStats
    from gsgs_engine.train.techniques.absgrad import AbsoluteGradients

    if not cpu_backend.available():
        pytest.skip(f"compiled CPU rasteriser unavailable: {cpu_backend.unavailable_reason()}")
    scene = load_dynamic_scene(clip, train_cameras=2)
    trainer = SpacetimeTrainer(scene, _config(iters=6, densify=True, backend="cpu"))
    trainer.setup()
    trainer.add_technique(AbsoluteGradients())
    fed = []
    plain = DensifyStats.accumulate

    def spy(self, grad, radii, width, height):
        r, _ = trainer.last_step_renders[0]
        fed.append(grad is not None and grad is r.means2d.absgrad)
        return plain(self, grad, radii, width, height)

    monkeypatch.setattr(DensifyStats, "accumulate", spy)
    trainer.train()
    assert fed and all(fed)
