"""Trainer: losses go down, adversarial starts stay finite, NaN steps are skipped, resume, densify."""

from __future__ import annotations

import math
import sys
import types

import numpy as np
import pytest
import torch

from gsgs_engine.cameras import Camera
from gsgs_engine.io.scene import Scene, View
from gsgs_engine.train.technique import Technique

SIZE = 32


class Probe(Technique):
    """A technique made of plain functions, for tests: `loss(ctx)` -> tensor | (weight, tensor) | None
    becomes the term `name`; `after(trainer, step)` runs after every step."""

    def __init__(self, name: str = "probe", loss=None, after=None):
        self.name, self._loss, self._after = name, loss, after

    def loss_terms(self, ctx):
        value = self._loss(ctx) if self._loss else None
        return None if value is None else {self.name: value}

    def after_step(self, trainer, step):
        if self._after:
            self._after(trainer, step)


# -- stand-ins for modules other engineers are still writing (used only while absent) ---------

def _install_metrics_standin() -> None:
    try:
        import gsgs_engine.metrics  # noqa: F401
        return
    except ImportError:
        pass

    def _window(size=11, sigma=1.5):
        x = torch.arange(size, dtype=torch.float32) - size // 2
        g = torch.exp(-x ** 2 / (2 * sigma ** 2))
        g = g / g.sum()
        return (g[:, None] * g[None, :])[None, None].repeat(3, 1, 1, 1)

    def ssim(img, gt):
        a = img.permute(2, 0, 1)[None]
        b = gt.permute(2, 0, 1)[None]
        w = _window().to(a.dtype)
        f = lambda x: torch.nn.functional.conv2d(x, w, padding=5, groups=3)  # noqa: E731
        mu_a, mu_b = f(a), f(b)
        saa, sbb, sab = f(a * a) - mu_a ** 2, f(b * b) - mu_b ** 2, f(a * b) - mu_a * mu_b
        c1, c2 = 0.01 ** 2, 0.03 ** 2
        m = ((2 * mu_a * mu_b + c1) * (2 * sab + c2)) / ((mu_a ** 2 + mu_b ** 2 + c1) * (saa + sbb + c2))
        return m.mean()

    def psnr(img, gt):
        return -10 * torch.log10(((img - gt) ** 2).mean().clamp_min(1e-10))

    mod = types.ModuleType("gsgs_engine.metrics")
    mod.ssim, mod.psnr = ssim, psnr
    mod.lpips_or_none = lambda img, gt: (None, "stand-in metrics in tests")
    sys.modules["gsgs_engine.metrics"] = mod


_install_metrics_standin()


# -- tiny synthetic scenes ---------------------------------------------------------------------
def look_at(eye, target=(0.0, 0.0, 0.0), size=SIZE, fov_deg=50.0, name="") -> Camera:
    eye = np.asarray(eye, dtype=np.float64)
    f = np.asarray(target, dtype=np.float64) - eye
    f /= np.linalg.norm(f)
    r = np.cross(f, [0.0, 0.0, 1.0])
    r /= np.linalg.norm(r)
    d = np.cross(f, r)
    R = np.stack([r, d, f])
    focal = 0.5 * size / math.tan(math.radians(fov_deg) / 2)
    return Camera(R=R, t=-R @ eye, fx=focal, fy=focal, cx=size / 2, cy=size / 2, width=size, height=size, name=name)


def ring_cameras(n: int, radius: float = 4.0, size: int = SIZE, offset: float = 0.0, prefix="v") -> list[Camera]:
    cams = []
    for i in range(n):
        a = offset + 2 * math.pi * i / n
        cams.append(look_at((radius * math.cos(a), radius * math.sin(a), 1.0), size=size, name=f"{prefix}{i}"))
    return cams


def ground_truth_gaussians(n: int = 40, seed: int = 0) -> dict:
    g = torch.Generator().manual_seed(seed)
    return {"means": (torch.rand(n, 3, generator=g) - 0.5) * 1.6,
            "quats": torch.randn(n, 4, generator=g),
            "scales": torch.rand(n, 3, generator=g) * 0.15 + 0.05,
            "opacities": torch.rand(n, generator=g) * 0.5 + 0.5,
            "sh": (torch.rand(n, 1, 3, generator=g) - 0.5) / 0.2820948}


def render_ground_truth(gt: dict, cam: Camera, background=(1.0, 1.0, 1.0)) -> np.ndarray:
    from gsgs_engine.render import render

    with torch.no_grad():
        out = render(gt["means"], gt["quats"], gt["scales"], gt["opacities"], gt["sh"], cam, 0,
                     torch.tensor(background), backend="reference")
    return out.color.numpy().astype(np.float32)


def make_scene(n_train: int = 3, n_test: int = 2, size: int = SIZE, with_points: bool = True) -> Scene:
    gt = ground_truth_gaussians()
    cams = ring_cameras(n_train, size=size) + ring_cameras(n_test, size=size, offset=0.4, prefix="t")
    views = []
    for cam in cams:
        img = render_ground_truth(gt, cam)
        views.append(View(camera=cam, image_path=None, loader=lambda img=img: img))
    pts = gt["means"].numpy() + np.random.default_rng(1).normal(0, 0.05, (40, 3)).astype(np.float32)
    pts = np.concatenate([pts] * 3)  # >= 100 points: used as "the source's points"
    return Scene(views=views, splits={"train": list(range(n_train)), "test": list(range(n_train, n_train + n_test))},
                 source="synthetic", format="test", points=pts if with_points else None,
                 point_colors=np.full((len(pts), 3), 0.5, np.float32) if with_points else None)


def make_trainer(scene=None, tmp_path=None, **cfg):
    from gsgs_engine.train.trainer import TrainConfig, Trainer

    cfg.setdefault("backend", "auto")  # the compiled kernel when built: fast tests
    cfg.setdefault("init", "points")
    cfg.setdefault("sh_degree", 1)
    config = TrainConfig(**cfg)
    config.densify_config.max_gaussians = 400  # bounded cost per step: these tests must stay fast
    return Trainer(scene or make_scene(), config, checkpoint_dir=None if tmp_path is None else tmp_path / "ckpt")


def mean_train_l1(trainer) -> float:
    with torch.no_grad():
        return float(np.mean([(trainer.render(v.camera).color - trainer._targets[i]).abs().mean().item()
                              for i, v in enumerate(trainer.train_views)]))


# -- tests -----------------------------------------------------------------------------------
@pytest.mark.slow  # tens of steps: several seconds, far more on a loaded 2-core machine
def test_tiny_scene_trains_to_lower_loss():
    trainer = make_trainer(iters=60, densify=True)
    trainer.setup()
    before = mean_train_l1(trainer)
    trainer.train()
    after = mean_train_l1(trainer)
    assert trainer.step == 60 and trainer.nan_steps_skipped == 0
    assert after < 0.6 * before, (before, after)
    assert trainer.model.all_finite()


def _adversarial(kind: str):
    from gsgs_engine.gaussians import GaussianModel

    n = 1 if kind == "single" else 50
    g = torch.Generator().manual_seed(3)
    means = (torch.rand(n, 3, generator=g) - 0.5)
    log_scales = torch.full((n, 3), math.log(0.1))
    opac = torch.zeros(n)
    if kind == "huge_scales":
        log_scales[:] = math.log(50.0)
    if kind == "transparent":
        opac[:] = -14.0  # sigmoid ~ 1e-6
    quats = torch.randn(n, 4, generator=g)
    return GaussianModel(means, log_scales, quats, opac, torch.zeros(n, 1, 3), torch.zeros(n, 3, 3), 1)


@pytest.mark.parametrize("kind", ["huge_scales", "transparent", "single"])
def test_adversarial_starts_stay_finite(kind):
    trainer = make_trainer(iters=10)
    trainer.setup(initial_model=_adversarial(kind))
    trainer.train()
    assert trainer.step == 10
    assert trainer.model.all_finite()
    assert trainer.model.num_gaussians >= 1
    assert math.isfinite(trainer.last_losses["loss"]) or trainer.nan_steps_skipped > 0
    with torch.no_grad():
        out = trainer.render(trainer.train_views[0].camera)
    assert torch.isfinite(out.color).all()


def test_nan_loss_and_nan_gradient_steps_are_skipped():
    trainer = make_trainer(iters=12)
    trainer.setup()

    def poison(ctx):
        if ctx.step == 3:
            return torch.tensor(float("nan"))
        if ctx.step == 7:  # finite value (0), non-finite gradient (inf - inf)
            x = trainer.model.means[0, 0]
            return torch.sqrt(x - x)
        return None

    trainer.add_technique(Probe("poison", loss=poison))
    snapshots = {}
    trainer.add_technique(Probe("snapshots", after=lambda t, s: snapshots.__setitem__(s, t.model.means.detach().clone())))
    trainer.train(until=2)
    before = trainer.model.means.detach().clone()
    trainer.train(until=3)
    assert trainer.nan_steps_skipped == 1
    assert torch.equal(trainer.model.means.detach(), before)  # nothing written into the model
    trainer.train()
    assert trainer.nan_steps_skipped == 2
    assert torch.equal(snapshots[8], snapshots[8]) and 7 not in snapshots and 3 not in snapshots
    assert trainer.step == 12 and trainer.model.all_finite()
    for state in trainer.optimizer.state.values():
        assert all(torch.isfinite(v).all() for v in state.values() if torch.is_tensor(v))


@pytest.mark.slow  # tens of steps: several seconds, far more on a loaded 2-core machine
def test_checkpoint_resume_continues_same_schedule(tmp_path):
    from gsgs_engine.train import checkpoint as ckpt

    a = make_trainer(tmp_path=tmp_path, iters=60, checkpoint_every=10)
    a.setup()
    a.train(until=35)
    assert a.densify_log and a.densify_log[0]["step"] == 25  # the Gaussian count changed before the checkpoint
    assert [s for s, _ in ckpt.list_checkpoints(tmp_path / "ckpt")] == [20, 30]
    b = make_trainer(tmp_path=tmp_path, iters=999, checkpoint_every=10)  # the checkpoint's schedule wins
    b.setup(resume=True)
    assert b.step == 30 and b.config.iters == 60
    assert b.model.num_gaussians == len(b.stats.grad_accum) == a.densify_log[0]["num_gaussians"]
    b.train()
    assert b.step == 60 and b.model.all_finite()
    for group in b.optimizer.param_groups:
        p = group["params"][0]
        st = b.optimizer.state.get(p, {})
        if st:
            assert st["exp_avg"].shape == p.shape


@pytest.mark.slow  # tens of steps: several seconds, far more on a loaded 2-core machine
def test_resume_is_deterministic(tmp_path):
    a = make_trainer(tmp_path=tmp_path / "a", iters=20, checkpoint_every=10, seed=5)
    a.setup()
    a.train()
    b = make_trainer(tmp_path=tmp_path / "b", iters=20, checkpoint_every=10, seed=5)
    b.setup()
    b.train(until=12)
    b.save_checkpoint()
    c = make_trainer(tmp_path=tmp_path / "b", iters=20, checkpoint_every=10, seed=5)
    c.setup(resume=True)
    c.train()
    assert c.model.num_gaussians == a.model.num_gaussians
    assert torch.allclose(c.model.means, a.model.means, atol=1e-5)


def test_pseudo_views_add_named_terms():
    from gsgs_engine.train.techniques.pseudo_views import PseudoSupervision, PseudoView

    scene = make_scene()
    trainer = make_trainer(scene, iters=4)
    trainer.setup()
    test_view = scene.test[0]
    pseudo = trainer.add_technique(PseudoSupervision([PseudoView(test_view.camera, test_view.image(), weight=0.5,
                                                                 name="p0")]))
    seen = []
    trainer.add_technique(Probe(loss=lambda ctx: seen.append("pseudo" in ctx.shared) or None))
    trainer.train()
    assert seen == [True] * 4
    assert {"l1", "dssim", "pseudo_l1", "pseudo_dssim"} <= set(trainer.last_losses)
    with pytest.raises(Exception, match="pseudo view"):
        pseudo.set_views([PseudoView(test_view.camera, np.zeros((5, 5, 3)), name="bad")])


def test_random_background_recomposites_the_target():
    scene = make_scene()
    rgba = np.zeros((SIZE, SIZE, 4), np.float32)
    rgba[8:24, 8:24] = [1.0, 0.0, 0.0, 1.0]
    for v in scene.views:
        v.loader = lambda: rgba
    scene.has_alpha = True
    trainer = make_trainer(scene, iters=2, random_background=True)
    bg = torch.tensor([0.0, 0.0, 1.0])
    target = trainer._target(0, bg.to(trainer.device)).cpu()  # the trainer's device: cuda where gsplat works
    assert torch.allclose(target[0, 0], bg) and torch.allclose(target[16, 16], torch.tensor([1.0, 0.0, 0.0]))
    # the photo's premultiplied part is made once per view: later steps' targets are those of the formula, to the bit
    for other in (torch.tensor([0.2, 0.7, 0.1]), bg):
        a = trainer._alphas[0][..., None]
        expected = (trainer._targets[0] - trainer.background * (1 - a)) + other.to(trainer.device) * (1 - a)
        assert torch.equal(trainer._target(0, other.to(trainer.device)), expected)


def test_random_background_behind_rgb_photos_keeps_the_photo_and_learns_opaque_splats():
    """RGB views (no alpha): the step's background is random, the target stays the photo, so splats that let the
    background through cost loss and training covers the photos: rendered alpha rises above the fixed
    background's run, where the white background itself paints the photos' white."""
    scene = make_scene()
    assert not scene.has_alpha
    coverage = {}
    for random_bg in (False, True):
        trainer = make_trainer(scene, iters=40, random_background=random_bg, densify=False)
        trainer.setup()
        with torch.no_grad():  # the pixels the initial splats reach: there coverage can change within 40 steps
            reached = [trainer.render(v.camera).alpha > 0.3 for v in trainer.train_views]
        bgs = []
        trainer.add_technique(Probe(loss=lambda ctx: bgs.append(ctx.background.cpu().clone()) or None))
        trainer.train()
        assert torch.equal(trainer._target(0, bgs[-1].to(trainer.device)), trainer._targets[0])  # the photo itself
        distinct = {tuple(b.tolist()) for b in bgs}
        assert len(distinct) == (40 if random_bg else 1)
        with torch.no_grad():
            coverage[random_bg] = float(np.mean([trainer.render(v.camera).alpha[r].mean().item()
                                                 for v, r in zip(trainer.train_views, reached)]))
    assert coverage[True] > coverage[False] + 0.04, coverage  # measured 0.67 -> 0.75


def test_signal_finishes_step_and_checkpoints(tmp_path):
    import os
    import signal

    from gsgs_engine.train.trainer import TrainingInterrupted

    trainer = make_trainer(tmp_path=tmp_path, iters=50, checkpoint_every=0)
    trainer.setup()
    trainer.add_technique(Probe(after=lambda t, s: os.kill(os.getpid(), signal.SIGTERM) if s == 5 else None))
    with pytest.raises(TrainingInterrupted) as info:
        trainer.train()
    assert info.value.step == 5 and info.value.exit_code == 143
    assert info.value.checkpoint is not None and info.value.checkpoint.is_file()
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL


def test_cancel_request_stops_with_checkpoint(tmp_path):
    from gsgs_engine.train.trainer import TrainingCancelled

    trainer = make_trainer(tmp_path=tmp_path, iters=50)
    trainer.setup()
    trainer.cancel_check = lambda: trainer.step >= 3
    with pytest.raises(TrainingCancelled) as info:
        trainer.train()
    assert info.value.step == 3 and info.value.checkpoint.is_file()


# -- densification and schedule --------------------------------------------------------------
def _model_with_optimizer(n=6):
    from gsgs_engine.gaussians import GaussianModel
    from gsgs_engine.train.trainer import TrainConfig, Trainer

    means = torch.arange(n * 3, dtype=torch.float32).reshape(n, 3)
    m = GaussianModel(means, torch.full((n, 3), math.log(0.05)), torch.tensor([[1.0, 0, 0, 0]] * n),
                      torch.zeros(n), torch.zeros(n, 1, 3), torch.zeros(n, 3, 3), 1)
    t = Trainer.__new__(Trainer)
    t.model, t.config, t.extent = m, TrainConfig(), 1.0
    opt = t._make_optimizer()
    # fake Adam moments that identify their Gaussian (row i holds i)
    for group in opt.param_groups:
        p = group["params"][0]
        ident = torch.arange(n, dtype=torch.float32).reshape((n,) + (1,) * (p.dim() - 1)).expand_as(p).clone()
        opt.state[p] = {"step": torch.tensor(1.0), "exp_avg": ident, "exp_avg_sq": ident.clone()}
    return m, opt


def test_densify_clones_splits_prunes_and_keeps_adam_rows():
    from gsgs_engine.train.densify import DensifyConfig, DensifyStats, densify_and_prune

    m, opt = _model_with_optimizer(6)
    with torch.no_grad():
        m.params["log_scales"][1] = math.log(0.5)  # large -> split
        m.params["opacity_logits"][4] = -10.0  # transparent -> pruned
    stats = DensifyStats(6)
    stats.grad_accum[:] = torch.tensor([1e-3, 1e-3, 0, 0, 0, 0])  # Gaussians 0 (small) and 1 (large) are hot
    stats.denom[:] = 1
    info = densify_and_prune(m, opt, stats, extent=10.0, config=DensifyConfig(), prune_large=False,
                             generator=torch.Generator().manual_seed(0))
    assert (info["cloned"], info["split"]) == (1, 1)
    # 6 + 1 clone + 2 split children - 1 split parent - 1 transparent = 7
    assert m.num_gaussians == 7 == info["num_gaussians"]
    kept_means = m.means.detach()
    assert torch.equal(kept_means[:4], torch.tensor([[0, 1, 2], [6, 7, 8], [9, 10, 11], [15, 16, 17.]]))
    means_state = opt.state[m.params["means"]]["exp_avg"]
    assert torch.equal(means_state[:4, 0], torch.tensor([0.0, 2, 3, 5]))  # original rows follow their Gaussians
    assert torch.all(means_state[4:] == 0)  # new Gaussians start with zero moments
    children = m.params["log_scales"].detach()[5:]
    assert torch.allclose(children, torch.full((2, 3), math.log(0.5 / 1.6)))
    for group in opt.param_groups:
        p = group["params"][0]
        assert p is m.params[group["name"]] and opt.state[p]["exp_avg"].shape == p.shape
    assert len(stats.grad_accum) == 7 and stats.grad_accum.sum() == 0


def test_densify_respects_gaussian_budget_and_never_empties():
    from gsgs_engine.train.densify import DensifyConfig, DensifyStats, densify_and_prune, reset_opacity

    m, opt = _model_with_optimizer(6)
    stats = DensifyStats(6)
    stats.grad_accum[:] = 1.0
    stats.denom[:] = 1
    densify_and_prune(m, opt, stats, 1.0, DensifyConfig(max_gaussians=8), prune_large=False)
    assert m.num_gaussians == 8
    with torch.no_grad():
        m.params["opacity_logits"][:] = -20.0
    densify_and_prune(m, opt, DensifyStats(8), 1.0, DensifyConfig(), prune_large=True)
    assert m.num_gaussians == 1
    reset_opacity(m, opt)
    assert float(m.opacities.detach().max()) <= 0.0100001


def test_accumulate_uses_ndc_units():
    from gsgs_engine.train.densify import DensifyStats

    s = DensifyStats(2)
    s.accumulate(torch.tensor([[1e-5, 0.0], [1.0, 1.0]]), torch.tensor([3, 0]), width=200, height=100)
    assert s.denom.tolist() == [1.0, 0.0]
    assert math.isclose(float(s.grad_accum[0]), 1e-5 * 100, rel_tol=1e-5)
    assert s.max_radii.tolist() == [3.0, 0.0]
    s.accumulate(torch.tensor([[float("nan"), 0.0], [0.0, 0.0]]), torch.tensor([3, 3]), 200, 100)
    assert s.denom.tolist() == [1.0, 0.0]  # a non-finite gradient is ignored


def test_schedule_scales_with_iterations():
    from gsgs_engine.train.schedule import Schedule, position_lr

    full = Schedule.scaled(30_000)
    assert (full.densify_from, full.densify_until, full.densify_every, full.opacity_reset_every,
            full.sh_degree_every) == (500, 15_000, 100, 3_000, 1_000)
    short = Schedule.scaled(3_000)
    assert (short.densify_from, short.densify_until, short.densify_every, short.opacity_reset_every,
            short.sh_degree_every) == (50, 1_500, 25, 300, 100)
    assert short.is_densify_step(75) and not short.is_densify_step(50) and not short.is_densify_step(1525)
    to_end = Schedule.scaled(1_000)
    to_end.densify_until = 1_000  # as opacity decay sets it: densify to the end, but never at the last step
    assert [s for s in range(951, 1_001) if to_end.is_densify_step(s)] == [975]
    assert [s for s in range(1, 30_001) if full.is_opacity_reset_step(s)] == [3000, 6000, 9000, 12000]  # as 3DGS
    tiny = Schedule.scaled(200)  # reset period 75 > densify_until - 75: no reset the prune cannot recover from
    assert not any(tiny.is_opacity_reset_step(s) for s in range(1, 201))
    assert math.isclose(position_lr(0, 100, 1.6e-4, 1.6e-6), 1.6e-4)
    assert math.isclose(position_lr(100, 100, 1.6e-4, 1.6e-6), 1.6e-6)
    assert math.isclose(position_lr(50, 100, 1.6e-4, 1.6e-6), 1.6e-5, rel_tol=1e-9)


def test_position_lr_scale_multiplies_the_means_rate_at_every_step_and_one_is_3dgs():
    from gsgs_engine import GsgsError
    from gsgs_engine.train.schedule import position_lr
    from gsgs_engine.train.trainer import TrainConfig, validate_config

    seen = {}

    def record(trainer, step):
        seen.setdefault(trainer.config.position_lr_scale, []).append(
            next(g["lr"] for g in trainer.optimizer.param_groups if g["name"] == "means"))

    finals = {}
    for scale in (None, 1.0, 3.0):
        trainer = make_trainer(iters=4, densify=False, position_lr_scale=scale)
        trainer.setup()
        trainer.add_technique(Probe(after=record))
        trainer.train()
        finals[scale] = trainer.model.means.detach().clone()
        lr = trainer.config.lr
        expected = [(scale or 1.0) * position_lr(s, 4, lr.position_init * trainer.extent,
                                                 lr.position_final * trainer.extent) for s in range(1, 5)]
        assert seen[scale] == pytest.approx(expected, rel=1e-12)
    assert torch.equal(finals[None], finals[1.0])  # unset is 3DGS's schedule, to the bit
    assert not torch.equal(finals[3.0], finals[1.0])
    for bad in (0.0, -1.0, float("nan"), float("inf"), 101.0):
        with pytest.raises(GsgsError, match="position-lr-scale"):
            validate_config(TrainConfig(position_lr_scale=bad))


def test_attribute_lr_scale_multiplies_colour_scale_and_rotation_rates_only():
    from gsgs_engine import GsgsError
    from gsgs_engine.train.trainer import TrainConfig, validate_config

    rates = {}
    for scale in (None, 1.0, 3.0):
        trainer = make_trainer(iters=2, densify=False, attribute_lr_scale=scale)
        trainer.setup()
        rates[scale] = {g["name"]: g["lr"] for g in trainer.optimizer.param_groups}
    assert rates[None] == rates[1.0]  # unset is 3DGS's rates
    for name in ("sh_dc", "sh_rest", "log_scales", "quats"):
        assert rates[3.0][name] == pytest.approx(3.0 * rates[1.0][name], rel=1e-12)
    for name in ("means", "opacity_logits"):  # positions have their own multiple; opacities stay 3DGS's
        assert rates[3.0][name] == rates[1.0][name]
    assert TrainConfig(attribute_lr_scale=3.0).lr == TrainConfig().lr  # the config's own rates are not changed
    for bad in (0.0, -1.0, float("nan"), float("inf"), 101.0):
        with pytest.raises(GsgsError, match="attribute-lr-scale"):
            validate_config(TrainConfig(attribute_lr_scale=bad))


def test_photometric_terms_weighting():
    from gsgs_engine.train.losses import photometric_terms, total_loss

    a = torch.zeros(16, 16, 3)
    b = torch.full((16, 16, 3), 0.5)
    terms = photometric_terms(a, b, lambda_dssim=0.2)
    assert math.isclose(terms["l1"][0], 0.8) and math.isclose(terms["dssim"][0], 0.2)
    assert math.isclose(float(terms["l1"][1]), 0.5)
    assert math.isclose(float(total_loss(terms)), 0.8 * 0.5 + 0.2 * float(terms["dssim"][1]), rel_tol=1e-6)
    assert float(total_loss(photometric_terms(b, b))) < 1e-6


def test_size_extent_is_the_camera_extent_for_orbits_and_the_scene_depth_for_forward_rigs():
    """The world-size prune's scale: an object inside a camera circle keeps the camera extent;
    a forward-facing rig (small baseline, far points) gets the points' median distance."""
    from gsgs_engine.train.trainer import size_extent

    rng = np.random.default_rng(0)
    angles = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    orbit = np.stack([4 * np.cos(angles), 4 * np.sin(angles), np.full(8, 1.0)], axis=1)
    inside = rng.uniform(-1, 1, size=(500, 3))
    assert size_extent(4.4, orbit, inside) == 4.4
    rig = np.stack([np.linspace(-1, 1, 3), np.zeros(3), np.zeros(3)], axis=1)
    far = np.concatenate([rng.uniform(-10, 10, size=(500, 2)), rng.uniform(40, 60, size=(500, 1))], axis=1)
    got = size_extent(1.1, rig, far)
    assert 40 < got < 62
    assert size_extent(1.1, rig, np.full((3, 3), np.nan)) == 1.1  # no usable points: camera extent
