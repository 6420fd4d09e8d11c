"""Training on one device: the trainer resolves it from the backend, and every training tensor lives there.

The "cuda" cases run only where CUDA and gsplat both work (gsgs_engine.render.api.cuda_status()); elsewhere
they skip saying which is missing. On a GPU machine:
    python -m pytest tests/test_train_device.py -q -rs
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from gsgs_engine import GsgsError
from gsgs_engine.render import api
from gsgs_engine.train.schedule import Schedule
from test_trainer import SIZE, make_scene, mean_train_l1

CUDA_OK, CUDA_REASON = api.cuda_status()
needs_cuda = pytest.mark.skipif(not CUDA_OK, reason=f"CUDA backend unavailable: {CUDA_REASON}")
DEVICES = ["cpu", pytest.param("cuda", marks=[needs_cuda, pytest.mark.gpu])]


def cpu_backend() -> str:
    """The backend that trains on the CPU whatever this machine has (auto would pick CUDA where it works)."""
    return "cpu" if api.cpu_status()[0] else "reference"


def backend_for(device: str) -> str:
    return "cuda" if device == "cuda" else cpu_backend()


def iters_with_densification(at_least: int = 30) -> int:
    """The shortest run (>= at_least steps) whose scaled 3DGS schedule densifies at least once."""
    for iters in range(at_least, 1000):
        s = Schedule.scaled(iters)
        if any(s.is_densify_step(k) for k in range(1, iters + 1)):
            return iters
    raise AssertionError("no run length below 1000 steps densifies")


def rgba_scene(n_train: int = 2, n_test: int = 1):
    """make_scene's views with an alpha channel (covered where the render differs from the white background)."""
    scene = make_scene(n_train=n_train, n_test=n_test)
    for v in scene.views:
        rgb = v.image()
        alpha = (np.abs(rgb - 1.0).max(axis=2) > 0.02).astype(np.float32)
        v.loader = lambda rgba=np.concatenate([rgb, alpha[..., None]], axis=2): rgba
    scene.has_alpha = True
    return scene


def config(device: str, **kw):
    from gsgs_engine.train.trainer import TrainConfig

    kw.setdefault("init", "points")
    kw.setdefault("sh_degree", 1)
    kw.setdefault("checkpoint_every", 0)
    cfg = TrainConfig(backend=backend_for(device), **kw)
    cfg.densify_config.max_gaussians = 400  # bounded cost per step
    return cfg


def training_tensors(trainer) -> dict[str, torch.Tensor]:
    """Every tensor the training loop keeps between steps, by name."""
    found = {f"param.{k}": v for k, v in trainer.model.params.items()}
    for group in trainer.optimizer.param_groups:
        for key, value in trainer.optimizer.state.get(group["params"][0], {}).items():
            if key != "step":  # Adam keeps its step counter on the CPU by design (not capturable)
                found[f"adam.{group['name']}.{key}"] = value
    for key in ("grad_accum", "denom", "max_radii"):
        found[f"stats.{key}"] = getattr(trainer.stats, key)
    found.update({f"target.{i}": t for i, t in enumerate(trainer._targets)})
    found.update({f"alpha.{i}": a for i, a in enumerate(trainer._alphas) if a is not None})
    pseudo = trainer.technique("pseudo_views")
    found.update({f"pseudo_target.{i}": t for i, t in enumerate(pseudo._targets if pseudo else [])})
    found["background"] = trainer.background
    rng = trainer.torch_gen.get_state()
    found["step_background"] = trainer._step_background()
    trainer.torch_gen.set_state(rng)  # looking must not change the run
    return found


def assert_on(tensors: dict[str, torch.Tensor], device: torch.device) -> None:
    wrong = {k: str(v.device) for k, v in tensors.items() if v.device != device}
    assert not wrong, f"not on {device}: {wrong}"


def all_tensors(obj, path="state"):
    if isinstance(obj, torch.Tensor):
        yield path, obj
    elif isinstance(obj, dict):
        for k, v in obj.items():
            yield from all_tensors(v, f"{path}.{k}")
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            yield from all_tensors(v, f"{path}[{i}]")


# -- (a) one device for everything -------------------------------------------------------------------
@pytest.mark.parametrize("device", DEVICES)
def test_training_runs_on_the_resolved_device(device, tmp_path):
    from gsgs_engine.gaussians import GaussianModel
    from gsgs_engine.io.ply import read_gaussian_ply
    from gsgs_engine.train import checkpoint as ckpt
    from gsgs_engine.reconstruct import train_and_export
    from gsgs_engine.train.techniques.pseudo_views import PseudoSupervision, PseudoView
    from gsgs_engine.train.trainer import Trainer

    scene = rgba_scene(n_train=2, n_test=1)
    iters = iters_with_densification(30)
    cfg = config(device, iters=iters, checkpoint_every=20, random_background=True)
    seen: dict = {}

    def setup(trainer):
        seen["trainer"] = trainer
        test_view = scene.test[0]
        trainer.add_technique(PseudoSupervision([PseudoView(test_view.camera, test_view.image(), weight=0.5,
                                                            name="p0")]))
        seen["l1_before"] = mean_train_l1(trainer)

    metrics = train_and_export(scene, cfg, tmp_path / "out", tmp_path / "ckpt", setup_trainer=setup)
    trainer = seen["trainer"]
    expected = torch.device("cuda", torch.cuda.current_device()) if device == "cuda" else torch.device("cpu")
    assert trainer.device == expected
    assert_on(training_tensors(trainer), expected)
    assert trainer.backend_used == ("cuda" if device == "cuda" else cpu_backend())

    # it trained: densification happened and the loss fell
    assert trainer.step == iters and trainer.nan_steps_skipped == 0 and trainer.model.all_finite()
    assert trainer.densify_log, "no densification in the run"
    assert mean_train_l1(trainer) < seen["l1_before"]
    assert {"pseudo_l1", "pseudo_dssim"} <= set(trainer.last_losses)

    # results: metrics.json records the device; the PLY and the test renders are written
    saved = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert saved["plan"]["device"] == metrics["plan"]["device"] == trainer.device_description
    if device == "cuda":
        assert saved["plan"]["device"].startswith(f"{expected} (") and saved["plan"]["backend"] == "cuda"
    else:
        assert saved["plan"]["device"] == "cpu"
    assert saved["iterations"] == iters and np.isfinite(saved["psnr"])
    model = GaussianModel.from_ply(read_gaussian_ply(tmp_path / "out" / "point_cloud.ply"))
    assert model.num_gaussians == saved["num_gaussians"] == trainer.model.num_gaussians and model.all_finite()
    assert np.allclose(model.means.detach().numpy(), trainer.model.means.detach().cpu().numpy())
    assert len(list((tmp_path / "out" / "renders").glob("*.png"))) == 1

    # the checkpoint holds CPU tensors only, wherever it was made (read with the engine's own reader: a safetensors
    # file: torch.load read it with torch 2.13 here and raised UnpicklingError with 2.11 on the H200, session 33)
    newest = ckpt.latest_checkpoint(tmp_path / "ckpt")
    raw = ckpt.load_checkpoint(newest)
    on_gpu = [p for p, t in all_tensors(raw) if t.device.type != "cpu"]
    assert not on_gpu, on_gpu

    # and it resumes on the CPU: drop the final one, continue from the step-40-ish one with a CPU backend
    steps = [s for s, _ in ckpt.list_checkpoints(tmp_path / "ckpt")]
    assert steps[-1] == iters and len(steps) == 2
    final = {k: v.detach().cpu().clone() for k, v in trainer.model.params.items()}
    newest.unlink()
    resumed = Trainer(scene, config("cpu", iters=iters, checkpoint_every=20, random_background=True),
                      checkpoint_dir=tmp_path / "ckpt")
    resumed.setup(resume=True)
    resumed.add_technique(PseudoSupervision(trainer.technique("pseudo_views").views))
    assert resumed.device == torch.device("cpu") and resumed.step == steps[0]
    assert resumed.config.backend == cpu_backend()  # this run's choice, not the checkpoint's
    assert resumed.model.num_gaussians == len(resumed.stats.grad_accum)
    assert_on(training_tensors(resumed), torch.device("cpu"))
    resumed.train()
    assert resumed.step == iters and resumed.model.all_finite()
    assert_on(training_tensors(resumed), torch.device("cpu"))
    assert resumed.model.num_gaussians == final["means"].shape[0]
    if device == "cpu":  # the same computation from the same state
        assert all(torch.equal(resumed.model.params[k].detach(), v) for k, v in final.items())
    else:  # another rasteriser for the last steps: close, not identical
        assert (resumed.model.means.detach() - final["means"]).abs().max() < 0.05


@needs_cuda
@pytest.mark.gpu
def test_cuda_trainer_loads_gsplats_kernels_before_training(tmp_path):
    """gsplat's first-use build runs in the trainer's set-up (its "init" clock, a log line with its seconds), so the
    first training step is an ordinary one."""
    from gsgs_engine.render import cuda_backend
    from gsgs_engine.train.trainer import Trainer

    lines: list[str] = []
    cuda_backend._kernels_loaded = False  # as in a fresh process
    trainer = Trainer(rgba_scene(n_train=2, n_test=1), config("cuda", iters=5), log=lines.append)
    assert any(m.startswith("gsplat: CUDA kernels ready in ") for m in lines), lines
    assert trainer.phase_seconds["init"] > 0.0
    lines.clear()
    Trainer(rgba_scene(n_train=2, n_test=1), config("cuda", iters=5), log=lines.append)
    assert not any(m.startswith("gsplat:") for m in lines), lines  # once a process


@needs_cuda
@pytest.mark.gpu
def test_cpu_checkpoint_resumes_on_cuda(tmp_path):
    from gsgs_engine.train.trainer import Trainer

    scene = make_scene(n_train=2, n_test=1)
    iters = iters_with_densification(30)
    a = Trainer(scene, config("cpu", iters=iters, checkpoint_every=10), checkpoint_dir=tmp_path / "ckpt")
    a.setup()
    a.train(until=iters - 10)
    a.save_checkpoint()
    b = Trainer(scene, config("cuda", iters=iters, checkpoint_every=10), checkpoint_dir=tmp_path / "ckpt")
    b.setup(resume=True)
    assert b.device.type == "cuda" and b.step == iters - 10 and b.config.backend == "cuda"
    assert_on(training_tensors(b), b.device)
    for name, p in a.model.params.items():
        assert torch.equal(b.model.params[name].detach().cpu(), p.detach())
    b.train()
    assert b.step == iters and b.model.all_finite() and b.backend_used == "cuda"
    assert_on(training_tensors(b), b.device)


@pytest.mark.parametrize("device", DEVICES)
def test_4d_training_runs_on_the_resolved_device(device, tmp_path):
    from dataclasses import replace

    from gsgs_engine.io.scene import Scene, View
    from gsgs_engine.spacetime import SpacetimeModel
    from gsgs_engine.train.dynamic import SpacetimeTrainer

    base = make_scene(n_train=4, n_test=0)
    views = []
    for k, v in enumerate(base.train):  # two frames, two cameras each
        views.append(View(camera=replace(v.camera, time=float(k // 2)), image_path=None, loader=v.loader))
    scene = Scene(views=views, splits={"train": list(range(4))}, source="synthetic-4d", format="test")
    assert scene.has_time
    iters = iters_with_densification(30)
    trainer = SpacetimeTrainer(scene, config(device, iters=iters, init="random", random_init_points=150,
                                             sh_degree=0, checkpoint_every=20), checkpoint_dir=tmp_path / "ckpt")
    trainer.setup()
    assert isinstance(trainer.model, SpacetimeModel)
    trainer.train()
    assert trainer.densify_log and trainer.model.all_finite()
    assert_on(training_tensors(trainer), trainer.device)
    assert trainer.device.type == device
    trainer.save_checkpoint()
    resumed = SpacetimeTrainer(scene, config("cpu", iters=iters, init="random", random_init_points=150,
                                             sh_degree=0, checkpoint_every=20), checkpoint_dir=tmp_path / "ckpt")
    resumed.setup(resume=True)
    assert isinstance(resumed.model, SpacetimeModel) and resumed.step == iters
    assert_on(training_tensors(resumed), torch.device("cpu"))
    for name, p in trainer.model.params.items():
        assert torch.equal(resumed.model.params[name].detach(), p.detach().cpu()), name


@pytest.mark.parametrize("depth", ["sparse", "tiny-dpt"])
@pytest.mark.parametrize("device", DEVICES)
def test_prior_loop_terms_live_on_the_trainers_device(device, depth, tmp_path, monkeypatch):
    import gsgs_engine.reconstruct as reconstruct_module
    from gsgs_engine.priors.config import PriorConfig
    from gsgs_engine.reconstruct import run_prior_training

    if depth == "sparse":
        import cv2
        if not hasattr(cv2, "ximgproc"):
            pytest.skip("the sparse depth source needs cv2.ximgproc (opencv-contrib), absent here")
        source = "sparse"
    else:  # a depth-estimation model, run on the trainer's device
        pytest.importorskip("transformers")
        from gsgs_engine.priors.depth_estimators import save_tiny_dpt
        source = str(save_tiny_dpt(tmp_path / "dpt"))
    seen = {}
    original = reconstruct_module.train_and_export

    def keep_trainer(*args, setup_trainer=None, **kw):
        def setup(trainer):
            seen["trainer"] = trainer
            setup_trainer(trainer)
        return original(*args, setup_trainer=setup, **kw)

    monkeypatch.setattr(reconstruct_module, "train_and_export", keep_trainer)
    metrics = run_prior_training(make_scene(n_train=3, n_test=1), config(device, iters=40, sh_degree=0),
                                 PriorConfig(prior="warp", num_pseudo=3, rounds=1, warmup_fraction=0.5,
                                             depth_source=source),
                                 tmp_path / "out", tmp_path / "ckpt")
    trainer = seen["trainer"]
    assert metrics["iterations"] == 40 and len(metrics["prior_rounds"]) == 1
    assert "pseudo_l1" in metrics["final_losses"] and "depth_reg" in metrics["final_losses"]
    assert np.isfinite(metrics["final_losses"]["depth_reg"])
    assert_on(training_tensors(trainer), trainer.device)
    loop = trainer.technique("gsgs_prior")
    depth = {f"train_depth.{i}.{j}": t for i, pair in enumerate(trainer.technique("depth_regulariser").train_depth)
             for j, t in enumerate(pair)}
    depth.update({f"pseudo_depth.{i}.{j}": t for i, pair in enumerate(loop.pseudo_depth) for j, t in enumerate(pair)})
    assert depth and loop.pseudo_depth
    assert_on(depth, trainer.device)
    if source != "sparse":
        assert next(loop.estimator.model.parameters()).device == trainer.device


# -- (b) an explicit CUDA backend that cannot run stops at once --------------------------------------------
def _no_cuda(monkeypatch, reason="torch reports no CUDA device (torch.cuda.is_available() is False)"):
    monkeypatch.setattr(api, "cuda_status", lambda device=None: (False, reason))
    return reason


def test_backend_cuda_without_cuda_fails_clearly(monkeypatch):
    from gsgs_engine.train.trainer import TrainConfig, Trainer, resolve_device

    reason = _no_cuda(monkeypatch)
    with pytest.raises(GsgsError) as err:
        Trainer(make_scene(n_train=2, n_test=0), TrainConfig(backend="cuda", init="points"))
    msg = str(err.value)
    assert "--backend cuda" in msg and reason in msg and "pip install gsplat" in msg and "--backend auto" in msg
    assert resolve_device("auto") == (torch.device("cpu"), "cpu")  # auto falls back to the CPU quietly
    assert resolve_device(cpu_backend())[0] == torch.device("cpu")


def test_gsgs_train_backend_cuda_without_cuda_stops_before_reading_data(monkeypatch, tmp_path, capsys):
    from gsgs_engine.cli import main

    reason = _no_cuda(monkeypatch, "`import gsplat` failed (ModuleNotFoundError: No module named 'gsplat'); "
                                   "pip install gsplat for the CUDA backend")
    out = tmp_path / "run"
    assert main(["train", str(tmp_path / "no_such_scene"), "--out", str(out), "--backend", "cuda"]) == 2
    err = capsys.readouterr().err
    assert "--backend cuda cannot run here" in err and reason in err
    assert "no_such_scene" not in err  # it stopped before looking for the data
    assert not out.exists()


def test_job_with_backend_cuda_without_cuda_fails_clearly(monkeypatch, tmp_path):
    from gsgs_engine.job import Job
    from gsgs_engine.reconstruct import run_train_job

    _no_cuda(monkeypatch)
    job = Job.create(tmp_path / "job", "train", data={"path": str(tmp_path / "no_such_scene")},
                     settings={"iters": 5, "backend": "cuda"})
    with pytest.raises(GsgsError, match="--backend cuda cannot run here"):
        run_train_job(job)


@pytest.mark.skipif(CUDA_OK, reason="CUDA and gsplat work here: the real 'unavailable' error cannot happen")
def test_backend_cuda_error_names_what_is_really_missing():
    from gsgs_engine.train.trainer import TrainConfig, Trainer

    with pytest.raises(GsgsError, match="--backend cuda cannot run here") as err:
        Trainer(make_scene(n_train=2, n_test=0), TrainConfig(backend="cuda", init="points"))
    assert CUDA_REASON in str(err.value)


# -- (c) the CPU path: deterministic, nothing copied --------------------------------------------------------
def _cpu_run(scene, seed: int = 7):
    from gsgs_engine.train.techniques.pseudo_views import PseudoSupervision, PseudoView
    from gsgs_engine.train.trainer import Trainer

    trainer = Trainer(scene, config("cpu", iters=iters_with_densification(30), seed=seed, random_background=True))
    trainer.setup()
    test_view = scene.test[0]
    trainer.add_technique(PseudoSupervision([PseudoView(test_view.camera, test_view.image(), weight=0.5, name="p0")]))
    trainer.train()
    return trainer


def test_cpu_training_is_bit_identical_across_runs():
    scene = rgba_scene(n_train=2, n_test=1)
    a, b = _cpu_run(scene), _cpu_run(scene)
    assert a.device == b.device == torch.device("cpu") and a.densify_log
    assert a.densify_log == b.densify_log and a.last_losses == b.last_losses
    for name, p in a.model.params.items():
        assert torch.equal(p, b.model.params[name]), name


def test_moving_to_the_same_device_keeps_the_very_tensors():
    from gsgs_engine.gaussians import GaussianModel

    model = GaussianModel.from_points(np.random.default_rng(0).normal(size=(20, 3)), None, 1)
    before = dict(model.params)
    assert model.to("cpu") is model and model.device == torch.device("cpu")
    assert all(model.params[k] is v for k, v in before.items())


def test_auto_backend_on_a_machine_without_cuda_trains_on_the_cpu(monkeypatch, tmp_path):
    from gsgs_engine.train.trainer import TrainConfig
    from gsgs_engine.reconstruct import train_and_export

    _no_cuda(monkeypatch)
    cfg = TrainConfig(iters=3, backend="auto", init="points", sh_degree=0, checkpoint_every=0)
    metrics = train_and_export(make_scene(n_train=2, n_test=1), cfg, tmp_path / "out", tmp_path / "ckpt")
    assert metrics["plan"]["device"] == "cpu" and metrics["plan"]["backend"] in ("cpu", "reference")
    assert metrics["plan"]["resolution"] == [SIZE, SIZE]
