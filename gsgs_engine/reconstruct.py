"""One reconstruction, start to end: effect plan -> initialisation -> techniques -> trainer -> export -> evaluation.

Every way of training goes through here: `gsgs train` (commands/train.py), `gsgs run-job`
and the add-on's jobs (`run_train_job`), and the accuracy benchmark's cells.

- `train_with_effects` plans what to model for the scene (gsgs_engine.effect_plan), prints the
  plan and trains exactly that;
- `run_prior_training` resolves the GS-GS prior's plan (gsgs_engine.priors.config) and adds
  its techniques (gsgs_engine.train.techniques) to the trainer;
- `train_and_export` runs the trainer (gsgs_engine.train.trainer), writes point_cloud.ply,
  renders the test views and writes metrics.json.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

from gsgs_engine import GsgsError
from gsgs_engine.effect_plan import apply_effect_plan, plan_effects, scene_for_plan, shared_triangulation
from gsgs_engine.job import write_json_atomic
from gsgs_engine.machine import machine_record
from gsgs_engine.priors.config import PriorConfig, resolve_prior_plan
from gsgs_engine.train import checkpoint as ckpt
from gsgs_engine.train.trainer import TrainConfig, Trainer, TrainingCancelled, resolve_device, validate_config


def _append_log(path: Path | None, message: str) -> None:
    if path is None:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as fh:
        fh.write(time.strftime("%Y-%m-%d %H:%M:%S ") + message + "\n")


def train_and_export(scene, config: TrainConfig, out_dir: Path, checkpoint_dir: Path, job=None,
                     resume: bool = False, plan: dict | None = None, stream=None,
                     setup_trainer: Callable[[Trainer], None] | None = None) -> dict:
    """Train on `scene`, then write point_cloud.ply, renders/ of the test views and metrics.json.

    `job` (a gsgs_engine.job.Job, possibly only a folder without job.json) receives
    progress events and is polled for cancellation. Raises TrainingInterrupted /
    TrainingCancelled after saving a checkpoint. Returns the metrics dict.
    """
    from gsgs_engine.io.ply import write_gaussian_ply
    from gsgs_engine.progress import Progress
    from gsgs_engine.train.evaluate import evaluate_views, lpips_fields

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    log_path = job.log_path if job is not None else out_dir / "log.txt"
    progress = Progress("train", config.iters, job=job, stream=stream)

    def log(message: str) -> None:
        progress.message(message)
        _append_log(log_path, message)

    # A scene with time gets the 4D (SpacetimeGS-lite) trainer; a static scene never carries temporal params.
    from gsgs_engine.train.dynamic import make_trainer

    trainer = make_trainer(scene, config, checkpoint_dir=checkpoint_dir,
                           cancel_check=job.cancel_requested if job is not None else None, progress=progress, log=log)
    from gsgs_engine.io.images import check_decodable

    check_decodable(scene.test if "test" in scene.splits else [])  # a broken test image stops us now, not after training
    initial, init_info = None, None
    if config.init == "mvs" and not scene.has_time and not (
            resume and checkpoint_dir is not None and ckpt.latest_checkpoint(checkpoint_dir) is not None):
        # dense initialisation: multi-view stereo over the training views (known poses) + their SfM points
        from gsgs_engine.init.mvs import trainer_dense_init

        t0 = time.perf_counter()
        initial, init_info = trainer_dense_init(trainer, log=log)
        trainer.phase_seconds["init"] += time.perf_counter() - t0  # stereo, SfM points, initial Gaussians
    trainer.setup(resume=resume, initial_model=initial, init_info=init_info)
    if setup_trainer is not None:  # the orchestration adds the run's techniques here
        setup_trainer(trainer)
    progress.total = trainer.config.iters
    progress.start_step = trainer.step
    try:
        trainer.train()
    finally:
        progress.close()
    kernel_seconds = trainer.kernel_seconds()  # before evaluation renders add to the clocks
    if trainer.step >= trainer.config.iters and trainer.checkpoint_dir is not None:
        trainer.save_checkpoint()  # a later --resume finds the run complete and only re-exports

    from gsgs_engine.io.world_scale import ply_to_world

    write_gaussian_ply(out_dir / "point_cloud.ply", ply_to_world(trainer.model.to_ply(), scene.world_scale))
    if trainer.bg_sphere is not None:  # the learned wall behind the splats, beside the PLY (gsgs eval reads it)
        from gsgs_engine.train.background_sphere import TEXTURE_FILE
        from gsgs_engine.write_errors import writing

        with writing(out_dir / TEXTURE_FILE, "the background sphere's texture"):
            trainer.bg_sphere.write_texture(out_dir / TEXTURE_FILE)
    t0 = time.perf_counter()
    test_views = scene.test if "test" in scene.splits else []
    evaluation = evaluate_views(lambda cam: trainer.render(cam, sh_degree=trainer.model.max_sh_degree),
                                test_views, renders_dir=out_dir / "renders")
    trainer.phase_seconds["evaluate"] += time.perf_counter() - t0
    if test_views:
        log(f"test ({len(test_views)} views): PSNR {evaluation['psnr']:.2f} SSIM {evaluation['ssim']:.4f} "
            f"LPIPS {evaluation['lpips'] if evaluation['lpips'] is not None else 'n/a'}")
    first = trainer.train_views[0].camera
    full_plan = {
        "backend": trainer.backend_used or trainer.config.backend, "backend_requested": trainer.config.backend,
        "device": trainer.device_description, "prior": "none", "sh_degree": trainer.config.sh_degree,
        "init": trainer.init_info.to_dict(), "background": [float(x) for x in trainer.background],
        "random_background": bool(trainer.config.random_background),
        "resolution": [first.width, first.height], "train_ids": [v.name for v in trainer.train_views],
        "num_train_views": len(trainer.train_views), "num_test_views": len(test_views),
        "iters": trainer.config.iters, "seed": trainer.config.seed, "schedule": trainer.schedule.to_dict(),
        "scene_extent": trainer.extent, "size_extent": trainer.size_extent, "world_scale": scene.world_scale,
        "novel_view_near": trainer.config.novel_view_near,
        **({"background_sphere": trainer.bg_sphere.describe(scene.world_scale)} if trainer.bg_sphere is not None
           else {}),
        "lambda_dssim": trainer.config.lambda_dssim,
        "loss": "(1 - lambda) * L1 + lambda * (1 - SSIM) (eq. 11 without prior terms)",
        "densify_gradient": "|dL/d means2d| in NDC units (pixel gradient * (W/2, H/2)), threshold "
                            f"{trainer.config.densify_config.grad_threshold}",
        **(plan or {}),
    }
    metrics = {
        "psnr": evaluation["psnr"], "ssim": evaluation["ssim"], **lpips_fields(evaluation),
        "train_seconds": trainer.train_seconds, "iterations": trainer.step,
        "num_gaussians": trainer.model.num_gaussians, "nan_steps_skipped": trainer.nan_steps_skipped,
        "final_losses": trainer.last_losses, "init": trainer.init_info.to_dict(), "plan": full_plan,
        "phase_seconds": {k: round(v, 3) for k, v in trainer.phase_seconds.items()},
        # where the loop's time went: the compiled kernel's phases (this process; None off the CPU kernel) and
        # the forward work inside each technique (its extra renders and losses; their backward is in "backward")
        "kernel_seconds": None if kernel_seconds is None else {k: round(v, 3) for k, v in kernel_seconds.items()},
        "technique_seconds": {k: round(v, 3) for k, v in trainer.technique_seconds.items()},
        "densify_events": len(trainer.densify_log), "per_view": evaluation["per_view"],
        "techniques": {t.name: t.report() for t in trainer.techniques},
        "machine": machine_record(),  # another processor rounds differently (gsgs_engine.machine)
    }
    write_json_atomic(out_dir / "metrics.json", metrics)
    return metrics


def config_from_settings(settings: dict) -> TrainConfig:
    """Job settings (job.json "settings") -> TrainConfig; unknown keys are rejected by name.

    A "preset" fills the keys the job leaves out (gsgs_engine.job.settings_with_preset)."""
    from gsgs_engine.job import settings_with_preset
    from gsgs_engine.settings_schema import check_settings

    settings = settings_with_preset(check_settings(settings))
    allowed = {"iters", "sh_degree", "backend", "seed", "checkpoint_every", "lambda_dssim", "random_background",
               "init", "random_init_points", "mvs_max_side", "mvs_flow", "densify", "max_gaussians", "prior", "prior_settings",
               "coarse_fraction", "coarse_scale", "position_lr_scale", "attribute_lr_scale",
               "resolution_scale", "max_side", "background", "preset", "effects", "techniques"}
    unknown = sorted(set(settings) - allowed)
    if unknown:
        raise GsgsError(f"job.json: unknown training settings {unknown}; known: {sorted(allowed)}")
    cfg = TrainConfig()
    for key in ("iters", "sh_degree", "backend", "seed", "checkpoint_every", "lambda_dssim", "random_background",
                "init", "random_init_points", "mvs_max_side", "mvs_flow", "densify", "coarse_fraction",
                "coarse_scale"):
        if key in settings and settings[key] not in (None, "auto"):
            setattr(cfg, key, type(getattr(cfg, key))(settings[key]))
    for key in ("position_lr_scale", "attribute_lr_scale"):
        if settings.get(key) not in (None, "auto"):
            setattr(cfg, key, float(settings[key]))
    if "max_gaussians" in settings:
        cfg.densify_config.max_gaussians = int(settings["max_gaussians"])
    validate_config(cfg)
    return cfg


def run_train_job(job) -> None:
    """Task "train" / "validate" of a job folder: data and settings from job.json, results in job.result_dir.

    Resumes from job.checkpoint_dir when a checkpoint is there; a cancel request saves a
    checkpoint and leaves the status "cancelled".
    """
    from gsgs_engine.io import load_scene

    from gsgs_engine.job import settings_with_preset
    from gsgs_engine.settings_schema import check_data, check_settings

    data = check_data(job.spec.get("data") or {}, f"{job.spec_path} data")
    settings = check_settings(job.spec.get("settings"), f"{job.spec_path} settings")
    settings = settings_with_preset(settings)  # a "preset" fills what the job leaves out
    if not data.get("path", data.get("source")):
        raise GsgsError(f"{job.spec_path}: data.source is missing; name the scene folder to train on")
    path = Path(data.get("path", data.get("source")))
    if not path.is_absolute():
        path = job.root / path
    config = config_from_settings(settings)
    resolve_device(config.backend)  # backend "cuda" without CUDA / gsplat: stop before loading the data
    background = tuple(settings.get("background", data.get("background", (1.0, 1.0, 1.0))))
    scene = load_scene(path, format=data.get("format", "auto"), train_split=data.get("train_split"),
                       train_views=data.get("train_views"), train_ids=data.get("train_ids"),
                       resolution_scale=float(settings.get("resolution_scale", 1.0)), background=background,
                       frames=data.get("frames"), max_side=int(settings.get("max_side") or 0))
    resume = ckpt.latest_checkpoint(job.checkpoint_dir) is not None
    plan = {"data": str(path), "format": scene.format or data.get("format", "auto"),
            "train_split": data.get("train_split"), "frames": data.get("frames"),
            "resolution_scale": scene.resolution_scale, "max_side": int(settings.get("max_side") or 0) or None,
            "job": str(job.root)}
    from gsgs_engine.effect_plan import overrides_from_settings
    from gsgs_engine.io.world_scale import camera_dicts_to_internal
    from gsgs_engine.priors.config import prior_config_from_settings

    try:
        # the same effect plan as `gsgs train` (SH degree, background, pseudo views, depth, time), printed
        # to the job log and saved in metrics.json; the job's explicit settings override it
        train_with_effects(scene, config, prior_config_from_settings(settings), job.result_dir, job.checkpoint_dir,
                           overrides=overrides_from_settings(settings), job=job, resume=resume, plan=plan,
                           log=lambda m: _append_log(job.log_path, m),
                           authored_poses=camera_dicts_to_internal(job.spec.get("pseudo_poses"), scene.world_scale))
    except TrainingCancelled as exc:
        job.set_status("cancelled", f"cancelled at step {exc.step}; checkpoint {exc.checkpoint}; "
                                    "run the job again to resume")


def run_prior_training(scene, train_config, prior_config: PriorConfig, out_dir, checkpoint_dir, job=None,
                       resume: bool = False, plan: dict | None = None, authored_poses: list | None = None,
                       stream=None) -> dict:
    """Train with the GS-GS prior (or plainly when the plan says none); returns metrics.json's dict."""
    prior_plan = resolve_prior_plan(prior_config, len(scene.train))
    prior_plan["authored_poses"] = list(authored_poses or [])
    loop_holder: dict = {}
    from gsgs_engine.train.techniques.catalogue import make_techniques, parse_techniques

    techniques = parse_techniques(prior_config.techniques, "--techniques / job setting \"techniques\"")  # bad names stop here
    make_techniques(techniques)  # so do bad options

    def setup(trainer) -> None:
        for technique in make_techniques(techniques):
            trainer.add_technique(technique)
        if prior_plan["generator"] is None and not prior_plan.get("depth_source"):
            return
        if prior_plan.get("depth_source") == "sparse" and trainer.init_info.method in ("sfm", "points") and trainer.step == 0:
            prior_plan["_sparse_points"] = trainer.model.means.detach().cpu().numpy().copy()
        from gsgs_engine.train.techniques.prior_loop import PriorLoop

        loop_holder["loop"] = trainer.add_technique(PriorLoop(prior_config, prior_plan, Path(out_dir), log=trainer.log))

    merged = dict(plan or {})
    metrics = train_and_export(scene, train_config, out_dir, checkpoint_dir, job=job, resume=resume,
                               plan={**merged, "prior": prior_plan["prior"], "techniques": techniques}, stream=stream,
                               setup_trainer=setup)
    loop = loop_holder.get("loop")
    prior_plan.pop("_sparse_points", None)
    prior_plan["authored_poses"] = len(prior_plan["authored_poses"])
    metrics["plan"]["prior_plan"] = prior_plan
    if loop is not None:
        metrics["prior_rounds"] = loop.round_stats
    write_json_atomic(Path(out_dir) / "metrics.json", metrics)
    return metrics


def train_with_effects(scene, train_config, prior_config, out_dir, checkpoint_dir, overrides: dict | None = None,
                       job=None, resume: bool = False, plan: dict | None = None, stream=None, log=print,
                       authored_poses: list | None = None) -> dict:
    """Plan the effects, print the plan, train what it enables; metrics.json["plan"]["effects"] holds it."""
    effect_plan = plan_effects(scene, train_config, prior_config, overrides, log=log)
    log(effect_plan.format())
    tc, pc = apply_effect_plan(effect_plan, train_config, prior_config)
    scene = scene_for_plan(scene, effect_plan)
    merged = {**(plan or {}), "effects": effect_plan.to_dict()}
    with shared_triangulation(effect_plan, scene.train):
        metrics = run_prior_training(scene, tc, pc, out_dir, checkpoint_dir, job=job, resume=resume, plan=merged,
                                     stream=stream, authored_poses=authored_poses)
    metrics.setdefault("phase_seconds", {})["plan"] = round(effect_plan.seconds, 3)
    write_json_atomic(Path(out_dir) / "metrics.json", metrics)
    return metrics
