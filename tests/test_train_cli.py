"""`gsgs train` / `gsgs eval` / run_train_job end to end on a tiny NeRF-synthetic folder, and progress output."""

from __future__ import annotations

import io
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SIZE = 32


def _c2w_nerf(eye, target=(0.0, 0.0, 0.0)) -> list:
    """OpenGL camera-to-world (x right, y up, z backward) looking from `eye` at `target`."""
    eye = np.asarray(eye, float)
    f = np.asarray(target, float) - eye
    f /= np.linalg.norm(f)
    r = np.cross(f, [0, 0, 1.0])
    r /= np.linalg.norm(r)
    up = np.cross(r, f)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = r, up, -f, eye
    return m.tolist()


def write_tiny_blender_scene(root: Path, n_train: int = 2, n_test: int = 2) -> Path:
    """Render a few random Gaussians (reference backend) into a NeRF-synthetic folder with RGBA PNGs."""
    import cv2
    import torch

    from gsgs_engine.cameras import camera_from_nerf
    from gsgs_engine.render import render

    g = torch.Generator().manual_seed(0)
    n = 30
    gt = dict(means=(torch.rand(n, 3, generator=g) - 0.5) * 1.4, quats=torch.randn(n, 4, generator=g),
              scales=torch.rand(n, 3, generator=g) * 0.15 + 0.05, opacities=torch.rand(n, generator=g) * 0.4 + 0.6,
              sh=(torch.rand(n, 1, 3, generator=g) - 0.5) / 0.2820948)
    angle_x = 2 * math.atan(0.5 * SIZE / 35.0)
    for split, count, offset in (("train", n_train, 0.0), ("test", n_test, 0.5)):
        frames = []
        (root / split).mkdir(parents=True, exist_ok=True)
        for i in range(count):
            a = offset + 2 * math.pi * i / count
            c2w = _c2w_nerf((4 * math.cos(a), 4 * math.sin(a), 1.5))
            cam = camera_from_nerf(np.array(c2w), SIZE, SIZE, angle_x)
            with torch.no_grad():
                out = render(gt["means"], gt["quats"], gt["scales"], gt["opacities"], gt["sh"], cam, 0,
                             torch.zeros(3), backend="reference")
            alpha = out.alpha.clamp(0, 1).numpy()
            rgb = (out.color.numpy() / np.maximum(alpha, 1e-6)[..., None]).clip(0, 1)  # straight alpha
            rgba = np.concatenate([rgb, alpha[..., None]], -1)
            bgra = (rgba[..., [2, 1, 0, 3]] * 255 + 0.5).astype(np.uint8)
            cv2.imwrite(str(root / split / f"r_{i}.png"), bgra)
            frames.append({"file_path": f"./{split}/r_{i}", "transform_matrix": c2w})
        (root / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": angle_x, "frames": frames}))
    return root


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory) -> Path:
    return write_tiny_blender_scene(tmp_path_factory.mktemp("tiny") / "scene")


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    env.setdefault("OMP_NUM_THREADS", "2")
    return env


def _gsgs(*args, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "gsgs_engine", *map(str, args)], cwd=REPO, env=_env(),
                          capture_output=True, text=True, timeout=600, **kw)


def _check_result(out: Path, iters: int, n_test: int = 2) -> dict:
    from gsgs_engine.gaussians import GaussianModel
    from gsgs_engine.io.ply import read_gaussian_ply

    metrics = json.loads((out / "metrics.json").read_text())
    for key in ("psnr", "ssim", "lpips", "train_seconds", "iterations", "num_gaussians", "nan_steps_skipped",
                "plan", "phase_seconds", "init"):
        assert key in metrics, key
    assert metrics["iterations"] == iters
    assert metrics["lpips"] is not None or metrics["lpips_reason"]
    assert math.isfinite(metrics["psnr"]) and 0 < metrics["ssim"] <= 1
    model = GaussianModel.from_ply(read_gaussian_ply(out / "point_cloud.ply"))
    assert model.num_gaussians == metrics["num_gaussians"] and model.all_finite()
    assert len(list((out / "renders").glob("*.png"))) == n_test
    plan = metrics["plan"]
    assert plan["train_ids"] and plan["prior"] == "none" and plan["resolution"] == [SIZE, SIZE]
    return metrics


# -- in-process runs (fast) --------------------------------------------------------------------
def test_train_command_in_process_writes_everything(tiny_scene, tmp_path):
    from gsgs_engine.cli import main
    from gsgs_engine.job import ProgressReader, read_status

    out = tmp_path / "run"
    rc = main(["train", str(tiny_scene), "--out", str(out), "--iters", "12", "--sh-degree", "1", "--init-points", "300",
               "--checkpoint-every", "5"])
    assert rc == 0
    metrics = _check_result(out, 12)
    assert metrics["plan"]["background"] == [1.0, 1.0, 1.0] and metrics["plan"]["sh_degree"] == 1
    events = ProgressReader(out).poll()
    assert events and events[-1]["phase"] == "train" and any(e["step"] == 12 for e in events)
    assert read_status(out)["state"] == "ok"
    # eval from the PLY reproduces the training run's test numbers
    assert main(["eval", str(out), "--data", str(tiny_scene)]) == 0
    ev = json.loads((out / "eval.json").read_text())
    assert ev["psnr"] == pytest.approx(metrics["psnr"], abs=1e-4)
    assert ev["ssim"] == pytest.approx(metrics["ssim"], abs=1e-5)


def test_max_side_trains_and_evaluates_at_the_capped_size(tiny_scene, tmp_path):
    from gsgs_engine.cli import main

    out = tmp_path / "run"
    assert main(["train", str(tiny_scene), "--out", str(out), "--iters", "4", "--sh-degree", "0",
                 "--init-points", "200", "--max-side", str(SIZE // 2)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    plan = metrics["plan"]
    assert plan["resolution"] == [SIZE // 2, SIZE // 2] and plan["max_side"] == SIZE // 2
    assert plan["resolution_scale"] == pytest.approx(0.5)  # the scale used, which eval re-loads at
    assert main(["eval", str(out), "--data", str(tiny_scene)]) == 0
    ev = json.loads((out / "eval.json").read_text())
    assert ev["resolution_scale"] == pytest.approx(0.5) and ev["psnr"] == pytest.approx(metrics["psnr"], abs=1e-4)


def test_bad_arguments_fail_with_one_line(tiny_scene, tmp_path, capsys):
    from gsgs_engine.cli import main

    assert main(["train", str(tiny_scene), "--out", str(tmp_path / "a"), "--prior", "magic"]) == 2
    assert "--prior 'magic' is not available" in capsys.readouterr().err
    assert main(["train", str(tiny_scene), "--out", str(tmp_path / "b"), "--iters", "0"]) == 2
    assert "--iters must be at least 1" in capsys.readouterr().err
    assert main(["train", str(tiny_scene), "--out", str(tmp_path / "c"), "--max-side", "-1"]) == 2
    assert "--max-side must be at least 0" in capsys.readouterr().err
    assert main(["eval", str(tmp_path / "nothing"), "--data", str(tiny_scene)]) == 2
    assert "no point_cloud.ply" in capsys.readouterr().err


def test_run_train_job_trains_cancels_and_resumes(tiny_scene, tmp_path):
    from gsgs_engine.job import Job
    from gsgs_engine.commands.run_job import run as run_job
    from gsgs_engine.train import checkpoint as ckpt

    job = Job.create(tmp_path / "job", "train", data={"path": str(tiny_scene), "format": "blender"},
                     settings={"iters": 8, "sh_degree": 0, "checkpoint_every": 4, "random_init_points": 300})
    job.request_cancel()
    import argparse
    assert run_job(argparse.Namespace(job_dir=str(job.root))) == 0
    assert job.status()["state"] == "cancelled"
    assert ckpt.latest_checkpoint(job.checkpoint_dir) is not None
    job.cancel_path.unlink()
    assert run_job(argparse.Namespace(job_dir=str(job.root))) == 0
    assert job.status()["state"] == "ok"
    _check_result(job.result_dir, 8)
    # a job goes through the same effect plan as `gsgs train`; its explicit settings override the plan
    effects = json.loads((job.result_dir / "metrics.json").read_text())["plan"]["effects"]
    assert effects["sh_degree"]["value"] == 0 and effects["sh_degree"]["source"] == "user"
    assert "effect plan" in job.log_path.read_text().lower()


def test_job_settings_become_effect_overrides():
    from gsgs_engine import GsgsError
    from gsgs_engine.effect_plan import overrides_from_settings

    assert overrides_from_settings({"iters": 5}) == {}
    assert overrides_from_settings({"sh_degree": "auto"}) == {}
    assert overrides_from_settings({"sh_degree": 1, "random_background": True, "effects": "pseudo_views=off"}) == \
        {"sh_degree": 1, "background": "random", "pseudo_views": "off"}
    assert overrides_from_settings({"effects": {"depth": "off"}}) == {"depth": "off"}
    with pytest.raises(GsgsError):
        overrides_from_settings({"effects": "colour=7"})


def test_job_settings_are_checked(tmp_path):
    from gsgs_engine import GsgsError
    from gsgs_engine.reconstruct import config_from_settings

    cfg = config_from_settings({"iters": "50", "backend": "reference", "max_gaussians": 1000})
    assert cfg.iters == 50 and cfg.backend == "reference" and cfg.densify_config.max_gaussians == 1000
    with pytest.raises(GsgsError, match="unknown training settings"):
        config_from_settings({"iterz": 5})
    with pytest.raises(GsgsError, match="backend"):
        config_from_settings({"backend": "tpu"})
    assert config_from_settings({}).mvs_max_side == 256
    assert config_from_settings({"mvs_max_side": 512}).mvs_max_side == 512
    with pytest.raises(GsgsError, match="mvs_max_side"):
        config_from_settings({"mvs_max_side": 4})


# -- real subprocesses (slow on a shared 2-core machine: torch import per process) ----------------
@pytest.mark.slow
def test_gsgs_train_subprocess_end_to_end(tiny_scene, tmp_path):
    out = tmp_path / "run"
    t0 = time.monotonic()
    proc = _gsgs("train", tiny_scene, "--out", out, "--iters", "10", "--sh-degree", "0", "--init-points", "300")
    assert proc.returncode == 0, proc.stderr
    assert "done: 10 steps" in proc.stderr
    _check_result(out, 10)
    assert time.monotonic() - t0 < 300


@pytest.mark.slow
def test_sigterm_then_resume_finishes_the_same_schedule(tiny_scene, tmp_path):
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "gsgs_engine", "train", str(tiny_scene), "--out", str(out), "--iters", "80",
           "--sh-degree", "0", "--checkpoint-every", "1000", "--init-points", "300",
           "--backend", "reference"]  # slow enough to be stopped mid-run on any machine (a GPU finishes first)
    proc = subprocess.Popen(cmd, cwd=REPO, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 300
        step = 0
        while time.monotonic() < deadline and proc.poll() is None:
            lines = (out / "progress.jsonl").read_text().splitlines() if (out / "progress.jsonl").exists() else []
            steps = [json.loads(line)["step"] for line in lines if '"phase": "train"' in line]
            step = max(steps, default=0)
            if step >= 3:
                break
            time.sleep(0.2)
        assert step >= 3, "training did not start in time"
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 143, err
    assert "--resume" in err
    status = json.loads((out / "status.json").read_text())
    assert status["state"] == "cancelled" and "--resume" in status["message"]
    ckpts = list((out / "checkpoints").glob("ckpt_*.safetensors"))
    assert len(ckpts) == 1
    stopped_at = int(ckpts[0].stem.split("_")[1])
    assert 3 <= stopped_at < 80
    # resume with a different --iters: the checkpoint's schedule (80 steps) is kept
    proc2 = _gsgs("train", tiny_scene, "--out", out, "--iters", "5", "--sh-degree", "0", "--resume")
    assert proc2.returncode == 0, proc2.stderr
    assert f"resuming from" in proc2.stderr
    _check_result(out, 80)


# -- progress output -------------------------------------------------------------------------------
class _Tty(io.StringIO):
    def isatty(self):
        return True


def test_progress_lines_every_tenth_when_not_a_terminal(tmp_path):
    from gsgs_engine.job import Job, ProgressReader
    from gsgs_engine.progress import Progress

    stream = io.StringIO()
    job = Job(root=tmp_path)
    p = Progress("train", 100, job=job, stream=stream, emit_interval_s=1e9)
    for step in range(1, 101):
        p.update(step, {"loss": 1.0 / step})
    lines = stream.getvalue().splitlines()
    # the first step (so a log shows the run started), then each 10 %
    assert len(lines) == 11 and "1/100" in lines[0] and "100/100" in lines[-1] and "\r" not in stream.getvalue()
    events = ProgressReader(tmp_path).poll()
    assert [e["step"] for e in events] == [1, 100]  # first and last always; the rest throttled
    assert events[-1]["losses"]["loss"] == pytest.approx(0.01)


def test_progress_bar_redraws_in_place_on_a_terminal():
    from gsgs_engine.progress import Progress

    stream = _Tty()
    p = Progress("train", 3, stream=stream)
    for step in (1, 2, 3):
        p.update(step, force=True)
    p.close()
    text = stream.getvalue()
    assert text.count("\r") == 3 and text.endswith("\n") and "3/3" in text
