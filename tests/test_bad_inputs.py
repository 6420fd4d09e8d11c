"""Bad inputs meet one clear error, never a traceback, never silent garbage (issue 16).

Tiny data only (a 32 px NeRF-synthetic folder, 2 + 2 views, a handful of steps), in process
through `gsgs_engine.cli.main` so each case costs milliseconds to a few seconds.
"""

from __future__ import annotations

import json
import math
import os
import pickle
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from test_train_cli import write_tiny_blender_scene

FAST = ["--iters", "4", "--sh-degree", "0", "--init-points", "200", "--init", "random"]


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    return write_tiny_blender_scene(tmp_path_factory.mktemp("bad") / "scene")


def gsgs(capsys, *args) -> tuple[int, str, str]:
    from gsgs_engine.cli import main

    rc = main([str(a) for a in args])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def error_line(err: str) -> str:
    """The single `gsgs: error:` line a failure must end with (and no traceback)."""
    assert "Traceback" not in err, err
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert lines and lines[-1].startswith("gsgs: error: "), err
    return lines[-1]


def copy_scene(scene: Path, dest: Path) -> Path:
    shutil.copytree(scene, dest)
    return dest


# -- 1. a planted pickle never runs -------------------------------------------------------------
class _Payload:
    """Unpickling this runs a shell command (what a malicious checkpoint does)."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def _plant(path: Path, marker: Path, how: str) -> None:
    import torch

    evil = {"format": 1, "step": 3, "payload": _Payload(marker)}
    path.parent.mkdir(parents=True, exist_ok=True)
    if how == "pickle":
        path.write_bytes(pickle.dumps(evil))
    else:
        torch.save(evil, path)


def test_the_planted_payload_really_runs_code_when_unpickled(tmp_path):
    # the premise of the tests below: torch.load(weights_only=False), as gsgs used, runs the payload
    import torch

    marker = tmp_path / "ran"
    _plant(tmp_path / "x.pt", marker, "torch.save")
    torch.load(tmp_path / "x.pt", weights_only=False)
    assert marker.exists()


@pytest.mark.parametrize("name", ["ckpt_0000003.pt", "ckpt_0000003.safetensors"])
@pytest.mark.parametrize("how", ["pickle", "torch.save"])
def test_planted_pickle_never_runs_on_train_resume(scene, tmp_path, capsys, name, how):
    out, marker = tmp_path / "run", tmp_path / "ran"
    _plant(out / "checkpoints" / name, marker, how)
    rc, _, err = gsgs(capsys, "train", scene, "--out", out, "--resume", *FAST)
    assert not marker.exists(), "the planted pickle ran"
    assert rc == 2
    line = error_line(err)
    assert name in line and "never" in line and "unpickl" in line


@pytest.mark.parametrize("name", ["ckpt_0000003.pt", "ckpt_0000003.safetensors"])
def test_planted_pickle_never_runs_on_run_job(scene, tmp_path, capsys, name):
    from gsgs_engine.job import Job

    job = Job.create(tmp_path / "job", "train", data={"path": str(scene)}, settings={"iters": 4})
    marker = tmp_path / "ran"
    _plant(job.checkpoint_dir / name, marker, "torch.save")
    rc, _, err = gsgs(capsys, "run-job", job.root)
    assert not marker.exists(), "the planted pickle ran"
    assert rc == 2 and name in error_line(err)
    assert job.status()["state"] == "error" and "pickle" in job.status()["message"]


def test_corrupt_checkpoint_message_fits_run_job(scene, tmp_path, capsys):
    from gsgs_engine.job import Job

    job = Job.create(tmp_path / "job", "train", data={"path": str(scene)}, settings={"iters": 4})
    job.checkpoint_dir.mkdir(parents=True)
    (job.checkpoint_dir / "ckpt_0000003.safetensors").write_bytes(b"\x20\x00\x00\x00\x00\x00\x00\x00{\"a\": 1")
    rc, _, err = gsgs(capsys, "run-job", job.root)
    line = error_line(err)
    assert rc == 2 and "unreadable checkpoint" in line
    assert "job folder" in line and "without --resume" not in line


def test_checkpoint_round_trip_is_exact_and_holds_no_pickle(tmp_path):
    import torch

    from gsgs_engine.train import checkpoint as ckpt

    g = torch.Generator().manual_seed(3)
    opt_state = {0: {"step": torch.tensor(5.0), "exp_avg": torch.randn(4, 3, generator=g)}}
    state = {"format": 2, "rng": {"numpy": np.random.default_rng(7).bit_generator.state, "torch": torch.get_rng_state()},
             "optimizer": {"state": opt_state, "param_groups": [{"params": [0], "betas": (0.9, 0.999), "lr": 1e-3}]},
             "losses": {"loss": float("nan")}, "none": None, "empty": torch.zeros(0, 3)}
    path = ckpt.save_checkpoint(tmp_path, 5, state)
    back = ckpt.load_checkpoint(path)
    assert path.name == "ckpt_0000005.safetensors" and b"\x80\x04" not in path.read_bytes()[:2]
    assert back["rng"]["numpy"] == state["rng"]["numpy"]  # 128-bit PCG state, exact
    assert torch.equal(back["rng"]["torch"], state["rng"]["torch"])
    assert torch.equal(back["optimizer"]["state"][0]["exp_avg"], opt_state[0]["exp_avg"])
    assert back["optimizer"]["param_groups"][0]["betas"] == (0.9, 0.999)
    assert math.isnan(back["losses"]["loss"]) and back["none"] is None and back["empty"].shape == (0, 3)


def test_a_checkpoint_whose_header_length_looks_like_a_signature_still_loads(tmp_path):
    """A safetensors file starts with its header length (8 bytes, little-endian; the header is padded
    to 8 bytes). Its first byte is 0x80, a pickle's first byte, one time in 32, and its first two
    bytes "PK", a zip's, one in 8192. Such a real checkpoint must load."""
    import pickle

    import torch

    from gsgs_engine import GsgsError
    from gsgs_engine.train import checkpoint as ckpt

    def encoded(pad: int) -> tuple[dict, bytes]:
        state = {"pad": "x" * pad, "t": torch.arange(3.0)}
        return state, ckpt.encode_state(state)

    base = int.from_bytes(encoded(0)[1][:8], "little")
    for want, modulus in ((b"\x80", 256), (b"PK", 65536)):
        target = int.from_bytes(want.ljust(8, b"\x00"), "little")
        start = (target - base) % modulus  # each padding character adds one byte to the header
        found = [(st, d) for st, d in (encoded(start + k) for k in range(-16, 17) if start + k >= 0)
                 if d[:len(want)] == want]
        assert found, want
        state, data = found[0]
        back = ckpt.decode_state(data, tmp_path / "ckpt.safetensors")
        assert torch.equal(back["t"], state["t"]) and back["pad"] == state["pad"]
    # a real pickle and a too-short file are still refused by name
    with pytest.raises(GsgsError, match="a pickle"):
        ckpt.decode_state(pickle.dumps({"a": 1}, protocol=4), tmp_path / "p.safetensors")
    with pytest.raises(GsgsError, match="too short"):
        ckpt.decode_state(b"\x01\x02", tmp_path / "s.safetensors")


# -- 2. one validation layer for settings -----------------------------------------------------------
JOB_CASES = [
    ({"prior_settings": {"rounds": 1e9}}, "prior_settings.rounds must be at most 100"),
    ({"random_init_points": 1e9}, "random_init_points must be at most 2000000"),
    ({"iters": -10}, "iters must be at least 1"),
    ({"iters": "abc"}, "iters must be a whole number"),
    ({"iters": None}, "iters must be a whole number"),
    ({"seed": "x"}, "seed must be a whole number"),
    ({"background": "red"}, "background must be \"white\", \"black\" or [r, g, b]"),
    (["iters", 5], "settings must be an object"),
    ({"iters": 30.7}, "iters must be a whole number"),
    ({"max_gaussians": 0}, "max_gaussians must be at least 1"),
    ({"max_gaussians": -1}, "max_gaussians must be at least 1"),
    ({"prior_settings": {"warmup_fraction": 5}}, "warmup_fraction must be at most 1"),
    ({"prior_settings": {"num_pseudo": -3}}, "num_pseudo must be at least 0"),
    ({"resolution_scale": 1e6}, "resolution_scale must be at most 4"),
    ({"prior_settings": {"pseudo_weight": float("nan")}}, "pseudo_weight must be a finite number"),
    ({"prior_settings": {"pseudo_every": 0}}, "pseudo_every must be at least 1"),
    ({"prior_settings": {"ring_weight": -0.5}}, "ring_weight must be at least 0"),
    ({"prior_settings": {"ring_fraction": 1.5}}, "ring_fraction must be at most 1"),
    ({"position_lr_scale": 0}, "position_lr_scale must be greater than 0"),
    ({"position_lr_scale": "fast"}, "position_lr_scale must be a finite number"),
]


@pytest.mark.parametrize("settings,expected", JOB_CASES, ids=[c[1].split(" must")[0] + repr(c[0])[-12:] for c in JOB_CASES])
def test_job_settings_are_validated_before_anything_runs(scene, tmp_path, capsys, settings, expected):
    from gsgs_engine.job import Job

    job = Job.create(tmp_path / "job", "train", data={"path": str(scene)})
    spec = json.loads(job.spec_path.read_text())
    spec["settings"] = settings
    job.spec_path.write_text(json.dumps(spec))  # NaN is written as the bare token NaN, as a careless tool would
    rc, _, err = gsgs(capsys, "run-job", job.root)
    line = error_line(err)
    assert rc == 2 and expected in line, line
    if isinstance(settings, dict):
        assert "accepted" in line or "must be a" in line or "must be \"" in line
    assert job.status()["state"] == "error"
    assert not job.checkpoint_dir.exists() and not (job.root / "progress.jsonl").exists()


def test_integral_settings_are_converted(tmp_path):
    from gsgs_engine.settings_schema import check_settings

    out = check_settings({"iters": 1e3, "seed": "7", "background": [0, 0, 1], "prior_settings": {"rounds": 2.0}})
    assert out["iters"] == 1000 and isinstance(out["iters"], int) and out["seed"] == 7
    assert out["background"] == (0.0, 0.0, 1.0) and out["prior_settings"]["rounds"] == 2
    assert check_settings({"position_lr_scale": 3})["position_lr_scale"] == 3.0
    from gsgs_engine.reconstruct import config_from_settings

    assert config_from_settings({"position_lr_scale": 2.5}).position_lr_scale == 2.5
    assert config_from_settings({"position_lr_scale": "auto"}).position_lr_scale is None  # the plan's choice
    assert config_from_settings({}).position_lr_scale is None
    assert config_from_settings({"attribute_lr_scale": 3}).attribute_lr_scale == 3.0
    assert config_from_settings({"attribute_lr_scale": "auto"}).attribute_lr_scale is None


CLI_CASES = [
    (["--pseudo-weight", "nan"], "--pseudo-weight must be a finite number"),
    (["--pseudo-views", "-1"], "--pseudo-views must be at least 0"),
    (["--rounds", "1000000000"], "--rounds must be at most 100"),
    (["--init-points", "1000000000"], "--init-points must be at most 2000000"),
    (["--resolution-scale", "1e6"], "--resolution-scale must be at most 4"),
    (["--warmup-fraction", "5"], "--warmup-fraction must be at most 1"),
    (["--lambda-reg", "inf"], "--lambda-reg must be a finite number"),
    (["--position-lr-scale", "-2"], "--position-lr-scale must be greater than 0"),
    (["--attribute-lr-scale", "0"], "--attribute-lr-scale must be greater than 0"),
]


@pytest.mark.parametrize("flags,expected", CLI_CASES, ids=[c[0][0] for c in CLI_CASES])
def test_cli_flags_meet_the_same_rules(scene, tmp_path, capsys, flags, expected):
    out = tmp_path / "run"
    rc, _, err = gsgs(capsys, "train", scene, "--out", out, *flags)
    line = error_line(err)
    assert rc == 2 and expected in line and "accepted" in line or "must be a finite" in line, line
    assert not out.exists()


def test_camera_angle_x_text_is_a_clear_error(scene, tmp_path, capsys):
    bad = copy_scene(scene, tmp_path / "scene")
    meta = json.loads((bad / "transforms_train.json").read_text())
    meta["camera_angle_x"] = "abc"
    (bad / "transforms_train.json").write_text(json.dumps(meta))
    rc, _, err = gsgs(capsys, "train", bad, "--out", tmp_path / "run", *FAST)
    assert rc == 2 and "camera_angle_x must be a finite number (got 'abc')" in error_line(err)


def test_a_sheared_nerf_matrix_is_refused_like_an_inline_camera(scene, tmp_path, capsys):
    bad = copy_scene(scene, tmp_path / "scene")
    meta = json.loads((bad / "transforms_train.json").read_text())
    m = np.array(meta["frames"][0]["transform_matrix"])
    m[:3, 1] += 0.5 * m[:3, 0]  # a 0.5 shear
    meta["frames"][0]["transform_matrix"] = m.tolist()
    (bad / "transforms_train.json").write_text(json.dumps(meta))
    rc, _, err = gsgs(capsys, "train", bad, "--out", tmp_path / "run", *FAST)
    assert rc == 2 and "sheared" in error_line(err)


# -- 3. NaN / Inf never pass silently -------------------------------------------------------------------
def _splats(n: int, nan: bool = False):
    from gsgs_engine.io.ply import GaussianPly

    rng = np.random.default_rng(0)
    pos = rng.uniform(-1, 1, (n, 3)).astype(np.float32)
    if nan:
        pos[::2] = np.nan
    return GaussianPly(pos, np.zeros(n), np.full((n, 3), -3.0), np.tile([1.0, 0, 0, 0], (n, 1)),
                       np.zeros((n, 3)), np.zeros((n, 0, 3)))


@pytest.mark.parametrize("case", ["nan", "empty"])
def test_eval_refuses_a_nan_or_empty_ply(scene, tmp_path, capsys, case):
    from gsgs_engine.io.ply import write_gaussian_ply

    result = tmp_path / "result"
    result.mkdir()
    write_gaussian_ply(result / "point_cloud.ply", _splats(0) if case == "empty" else _splats(50, nan=True))
    rc, out, err = gsgs(capsys, "eval", result, "--data", scene)
    line = error_line(err)
    assert rc == 2 and "PSNR" not in out
    assert ("NaN or Inf" in line and "25 of 50" in line) if case == "nan" else "no Gaussians" in line
    assert not (result / "eval.json").exists()


def test_the_addon_reader_refuses_nan_splats(tmp_path):
    from gsgs_engine import GsgsError
    from gsgs_engine.io.ply import read_gaussian_ply, write_gaussian_ply

    write_gaussian_ply(tmp_path / "a.ply", _splats(10, nan=True))
    with pytest.raises(GsgsError, match="5 of 10 splats hold NaN or Inf values \\(in x/y/z\\)"):
        read_gaussian_ply(tmp_path / "a.ply")  # what gsgs_blender.splat_import calls


def test_json_outputs_never_hold_bare_nan(tmp_path):
    from gsgs_engine.job import Job, write_json_atomic

    write_json_atomic(tmp_path / "m.json", {"psnr": float("nan"), "per_view": [1.0, float("inf")]})
    strict = json.loads((tmp_path / "m.json").read_text(), parse_constant=lambda c: pytest.fail(f"bare {c}"))
    assert strict == {"psnr": None, "per_view": [1.0, None]}
    Job(root=tmp_path).emit("train", 3, 10, losses={"loss": float("nan")})
    line = (tmp_path / "progress.jsonl").read_text().strip()
    assert json.loads(line, parse_constant=lambda c: pytest.fail(f"bare {c}"))["losses"] == {"loss": None}


def test_inf_in_a_points_file_is_refused(scene, tmp_path, capsys):
    from gsgs_engine.io import load_scene
    from gsgs_engine.io.ply import write_ply_vertices
    from gsgs_engine.job import Job

    src = load_scene(scene)
    cams = [{**v.camera.to_dict(), "image": str(v.image_path), "split": "train"} for v in src.train]
    pts = np.random.default_rng(0).uniform(-1, 1, (500, 3)).astype(np.float32)
    pts[:7, 0] = np.inf
    pts[7:9, 2] = np.nan
    job = Job.create(tmp_path / "job", "train", data={"cameras": cams, "points": "points.ply"})
    write_ply_vertices(job.root / "points.ply", {"x": pts[:, 0], "y": pts[:, 1], "z": pts[:, 2]})
    rc, _, err = gsgs(capsys, "train", job.root, "--format", "job", "--out", tmp_path / "run", *FAST[:4])
    line = error_line(err)
    assert rc == 2 and "points.ply: 9 of 500 points have NaN or Inf coordinates" in line


def test_a_run_that_skips_many_steps_stops_naming_the_cause(scene, tmp_path):
    import torch

    from gsgs_engine.io import load_scene
    from gsgs_engine.train.nan_guard import TrainingDiverged
    from gsgs_engine.reconstruct import train_and_export
    from gsgs_engine.train.trainer import TrainConfig

    from test_trainer import Probe

    def poison(trainer):
        trainer.add_technique(Probe("pseudo_l1", loss=lambda ctx: (float("nan"), torch.tensor(0.5))))

    config = TrainConfig(iters=30, sh_degree=0, init="random", random_init_points=200, backend="cpu")
    with pytest.raises(TrainingDiverged) as info:
        train_and_export(load_scene(scene), config, tmp_path / "out", tmp_path / "out" / "checkpoints",
                         setup_trainer=poison)
    msg = str(info.value)
    assert "training stopped at step 4: 4 steps had a non-finite loss or gradient (at most 3 of 30 may)" in msg
    assert "loss term pseudo_l1 has weight nan (4 steps)" in msg
    assert not (tmp_path / "out" / "point_cloud.ply").exists() and not (tmp_path / "out" / "metrics.json").exists()


@pytest.mark.parametrize("bad, finite", [(None, True), (float("nan"), False), (float("inf"), False),
                                          (float("-inf"), False), ("inf-inf", False), ("overflow", True)])
def test_gradient_check_finds_every_non_finite_element_and_only_those(bad, finite):
    """The step's gradient check (one sum a tensor, element by element where a sum is not finite): NaN, Inf, -Inf
    and Inf next to -Inf are caught wherever they sit; finite values whose sum overflows float32 are not."""
    import torch

    from gsgs_engine.train.nan_guard import all_finite, grads_finite

    params = [torch.zeros(1000, 3, requires_grad=True), torch.zeros(1000, 1, requires_grad=True),
              torch.zeros(5, requires_grad=True)]
    params[0].grad = torch.randn(1000, 3)
    params[1].grad = torch.randn(1000, 1)  # params[2] has no gradient (None)
    g = params[1].grad
    if bad == "inf-inf":
        g[3, 0], g[900, 0] = float("inf"), float("-inf")
    elif bad == "overflow":
        g[:, 0] = 3e38  # every element finite, the float32 sum is Inf
        assert not torch.isfinite(g.sum())
    elif bad is not None:
        g[777, 0] = bad
    assert grads_finite(params) is finite
    assert all_finite(params[1].grad) is finite


# -- 4. a run folder belongs to one run -----------------------------------------------------------------
def test_run_folder_belongs_to_one_run(scene, tmp_path, capsys):
    out = tmp_path / "run"
    assert gsgs(capsys, "train", scene, "--out", out, *FAST)[0] == 0
    first = (out / "metrics.json").read_bytes()
    # a new run into the same folder is refused (the old checkpoints would be resumed later) ...
    rc, _, err = gsgs(capsys, "train", scene, "--out", out, *FAST[:2], "--sh-degree", "1", *FAST[4:])
    assert rc == 2 and "holds another run" in error_line(err) and "--overwrite" in error_line(err)
    assert (out / "metrics.json").read_bytes() == first
    # ... resuming it with other settings is refused, naming the difference ...
    rc, _, err = gsgs(capsys, "train", scene, "--out", out, "--resume", *FAST[:2], "--sh-degree", "1", *FAST[4:])
    assert rc == 2 and "sh_degree: 0 in the checkpoint, 1 now" in error_line(err)
    # ... and so is resuming it on other data with the same view names
    other = copy_scene(scene, tmp_path / "other")
    import cv2

    img = cv2.imread(str(other / "train" / "r_0.png"), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(other / "train" / "r_0.png"), img[::-1].copy())
    rc, _, err = gsgs(capsys, "train", other, "--out", out, "--resume", *FAST)
    assert rc == 2 and "trained on other data" in error_line(err)
    # --overwrite replaces the run: one run's progress, one run's checkpoints
    rc, _, _ = gsgs(capsys, "train", scene, "--out", out, "--overwrite", *FAST[:2], "--sh-degree", "1", *FAST[4:])
    assert rc == 0
    events = [json.loads(ln) for ln in (out / "progress.jsonl").read_text().splitlines()]
    assert sum(e["message"].startswith("init:") for e in events) == 1  # one run's progress, not two
    assert sum(e["message"].startswith("test (") for e in events) == 1
    assert json.loads((out / "metrics.json").read_text())["plan"]["sh_degree"] == 1
    # a matching resume still works (the run is complete: it re-exports)
    assert gsgs(capsys, "train", scene, "--out", out, "--resume", *FAST[:2], "--sh-degree", "1", *FAST[4:])[0] == 0


# -- 6. images decoded completely or rejected ----------------------------------------------------------------
def _jpeg_scene(scene: Path, dest: Path, cut: bool) -> Path:
    import cv2

    out = copy_scene(scene, dest)
    img = cv2.imread(str(out / "train" / "r_0.png"))
    (out / "train" / "r_0.png").unlink()
    ok, buf = cv2.imencode(".jpg", img)
    data = buf.tobytes()
    (out / "train" / "r_0.jpg").write_bytes(data[: len(data) // 2] if cut else data + b"\x00" * 16)
    return out


def test_a_truncated_jpeg_is_refused_and_a_padded_one_is_fine(scene, tmp_path, capsys):
    from gsgs_engine.io import load_scene

    cut = _jpeg_scene(scene, tmp_path / "cut", cut=True)
    rc, _, err = gsgs(capsys, "train", cut, "--out", tmp_path / "run", *FAST)
    assert rc == 2 and "r_0.jpg: the JPEG is truncated" in error_line(err)
    padded = _jpeg_scene(scene, tmp_path / "padded", cut=False)
    assert load_scene(padded).train[0].image().shape == (32, 32, 3)


def test_sfm_refuses_a_truncated_jpeg_and_tiny_photos(tmp_path, capsys):
    import cv2

    photos = tmp_path / "photos"
    photos.mkdir()
    img = (np.random.default_rng(0).uniform(0, 255, (64, 64, 3))).astype(np.uint8)
    for i in range(2):
        data = cv2.imencode(".jpg", img)[1].tobytes()
        (photos / f"p{i}.jpg").write_bytes(data if i else data[: len(data) // 2])
    rc, _, err = gsgs(capsys, "sfm", photos, "--out", tmp_path / "out")
    assert rc == 2 and "p0.jpg: cannot be read as an image (the JPEG is truncated" in error_line(err)
    tiny = tmp_path / "tiny"
    tiny.mkdir()
    for i in range(3):
        cv2.imwrite(str(tiny / f"t{i}.png"), img[:1, :1])
    rc, _, err = gsgs(capsys, "sfm", tiny, "--out", tmp_path / "out2")
    assert rc == 2 and "is 1x1 pixels" in error_line(err)


def test_a_broken_test_image_stops_the_run_before_training(scene, tmp_path, capsys):
    bad = copy_scene(scene, tmp_path / "scene")
    data = (bad / "test" / "r_1.png").read_bytes()
    (bad / "test" / "r_1.png").write_bytes(data[: len(data) // 2])
    out = tmp_path / "run"
    rc, _, err = gsgs(capsys, "train", bad, "--out", out, *FAST)
    assert rc == 2 and "r_1.png" in error_line(err)
    assert not (out / "checkpoints").exists() and not (out / "progress.jsonl").exists()


# -- 7. write errors, interrupts, stale status ------------------------------------------------------------------
def test_out_naming_a_file_or_inside_one(scene, tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("x")
    rc, _, err = gsgs(capsys, "train", scene, "--out", f, *FAST)
    assert rc == 2 and "--out names a file" in error_line(err)
    rc, _, err = gsgs(capsys, "train", scene, "--out", f / "sub", *FAST)
    assert rc == 2 and "cannot write" in error_line(err)


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root writes into read-only folders")
def test_out_in_a_read_only_folder(scene, tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        rc, _, err = gsgs(capsys, "train", scene, "--out", ro / "run", *FAST)
    finally:
        ro.chmod(0o755)
    assert rc == 2 and "cannot write" in error_line(err)


def test_eval_prints_metrics_before_failing_to_write(scene, tmp_path, capsys):
    out = tmp_path / "run"
    assert gsgs(capsys, "train", scene, "--out", out, *FAST)[0] == 0
    (out / "eval.json").mkdir()  # eval.json cannot be written (a folder stands there)
    rc, stdout, err = gsgs(capsys, "eval", out, "--data", scene)
    assert "PSNR" in stdout  # the numbers reach the user anyway
    line = error_line(err)
    assert rc == 2 and f"{out / 'eval.json'}: cannot write eval.json (Is a directory)" in line, line


def test_interrupt_during_start_up_or_final_evaluation_is_cancelled(scene, tmp_path, capsys, monkeypatch):
    import gsgs_engine.io
    import gsgs_engine.train.evaluate as evaluate
    from gsgs_engine.job import read_status

    def interrupt(*a, **k):
        raise KeyboardInterrupt

    with monkeypatch.context() as m:
        m.setattr(gsgs_engine.io, "load_scene", interrupt)
        rc, _, err = gsgs(capsys, "train", scene, "--out", tmp_path / "a", *FAST)
    assert rc == 130 and read_status(tmp_path / "a")["state"] == "cancelled" and "--resume" in err
    with monkeypatch.context() as m:
        m.setattr(evaluate, "evaluate_views", interrupt)
        rc, _, _ = gsgs(capsys, "train", scene, "--out", tmp_path / "b", *FAST)
    assert rc == 130 and read_status(tmp_path / "b")["state"] == "cancelled"


def test_sigterm_unwinds_like_ctrl_c():
    from gsgs_engine.write_errors import sigterm_interrupts

    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(KeyboardInterrupt):
        with sigterm_interrupts():
            os.kill(os.getpid(), signal.SIGTERM)
            signal.sigtimedwait([], 0) if hasattr(signal, "sigtimedwait") else None
            for _ in range(1000):
                pass
    assert signal.getsignal(signal.SIGTERM) == before


def test_a_running_status_with_a_dead_pid_is_stopped_unexpectedly(tmp_path):
    from gsgs_blender import job_runner
    from gsgs_engine.job import Job, status_is_stale

    job = Job.create(tmp_path / "job", "train", data={"path": "x"})
    job.set_status("running", "train started")
    status = job.status()
    assert status["pid"] == os.getpid() and not status_is_stale(status)  # this process lives
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    status["pid"] = dead.pid
    job.status_path.write_text(json.dumps(status))
    assert status_is_stale(job.status())
    run = job_runner.attach(job.root)
    assert run.state == "error" and run.message.startswith("stopped unexpectedly")
    other_host = {**status, "host": "another-node"}
    assert not status_is_stale(other_host)  # a cluster node's job is not judged from here


def test_outputs_are_0644(scene, tmp_path, capsys):
    old = os.umask(0o022)
    try:
        out = tmp_path / "run"
        assert gsgs(capsys, "train", scene, "--out", out, *FAST)[0] == 0
    finally:
        os.umask(old)
    modes = {p.name: p.stat().st_mode & 0o777 for p in
             [out / "metrics.json", out / "status.json", next((out / "checkpoints").iterdir())]}
    assert set(modes.values()) == {0o644}, modes


# -- 10. other ------------------------------------------------------------------------------------------------
def test_run_job_accepts_data_source(scene, tmp_path, capsys):
    from gsgs_engine.job import Job

    job = Job.create(tmp_path / "job", "train", data={"source": str(scene)},
                     settings={"iters": 3, "sh_degree": 0, "init": "random", "random_init_points": 200})
    rc, _, err = gsgs(capsys, "run-job", job.root)
    assert rc == 0, err
    assert job.status()["state"] == "ok" and (job.result_dir / "point_cloud.ply").is_file()


# -- 5. scale-free numerics ---------------------------------------------------------------------------------------
def _scaled_copy(scene: Path, dest: Path, s: float) -> Path:
    out = copy_scene(scene, dest)
    for f in out.glob("transforms_*.json"):
        meta = json.loads(f.read_text())
        for fr in meta["frames"]:
            m = np.array(fr["transform_matrix"])
            m[:3, 3] *= s
            fr["transform_matrix"] = m.tolist()
        f.write_text(json.dumps(meta))
    return out


@pytest.fixture(scope="module")
def scene4(tmp_path_factory) -> Path:
    return write_tiny_blender_scene(tmp_path_factory.mktemp("scale") / "scene", n_train=4, n_test=2)


def test_the_same_scene_trains_alike_at_any_scale(scene4, tmp_path, capsys):
    from gsgs_engine.io.ply import read_gaussian_ply

    psnr, ply = {}, {}
    for s in (1.0, 1e-4, 3e-3, 1e4):  # 3e-3: rescaled by 1e-2, so training sees another spread than at 1
        data = _scaled_copy(scene4, tmp_path / f"s{s:g}", s)
        out = tmp_path / f"run{s:g}"
        rc, _, err = gsgs(capsys, "train", data, "--out", out, "--iters", "60", "--sh-degree", "0",
                          "--init", "random", "--init-points", "500", "--backend", "cpu")
        assert rc == 0, err
        metrics = json.loads((out / "metrics.json").read_text())
        psnr[s] = metrics["psnr"]
        ply[s] = read_gaussian_ply(out / "point_cloud.ply")
        # the exported PLY is in the scene's own units; gsgs eval reads it back to the same numbers
        assert gsgs(capsys, "eval", out, "--data", data)[0] == 0
        assert json.loads((out / "eval.json").read_text())["psnr"] == pytest.approx(psnr[s], abs=1e-3)
    from gsgs_engine.io import load_scene
    from gsgs_engine.metrics import psnr as psnr_of

    import torch

    blank = np.mean([float(psnr_of(torch.ones(32, 32, 3), torch.from_numpy(v.image()))) for v in load_scene(scene4).test])
    assert psnr[1.0] > blank + 1.5, (psnr, blank)  # it trained (a blank render, as at 1e-3 before, scores `blank`)
    for s in (1e-4, 3e-3, 1e4):
        assert abs(psnr[s] - psnr[1.0]) < 0.2, psnr
    # a 1e-4 copy's splats are the original's, 1e-4 as large, in world units
    assert np.median(np.abs(ply[1e-4].positions)) == pytest.approx(1e-4 * np.median(np.abs(ply[1.0].positions)), rel=1e-2)
    assert np.median(ply[1e-4].log_scales) == pytest.approx(np.median(ply[1.0].log_scales) + np.log(1e-4), abs=0.05)


def test_pseudo_targets_bench_errors_are_one_line(scene, tmp_path):
    from gsgs_engine.io.ply import write_gaussian_ply

    write_gaussian_ply(tmp_path / "nan.ply", _splats(20, nan=True))
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    for args, expected in (([scene, tmp_path / "nan.ply"], "NaN or Inf"),
                           ([tmp_path / "nowhere", tmp_path / "nan.ply"], "no such file or folder"),
                           ([scene, tmp_path / "nan.ply", "--max-test", "0"], "--max-test must be at least 1")):
        proc = subprocess.run([sys.executable, "-m", "gsgs_engine", "bench", "pseudo-targets", *map(str, args)],
                              capture_output=True, text=True, env=env, timeout=300)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
        assert proc.stderr.strip().startswith("gsgs: error:")
        assert expected in proc.stderr


def _children(pid: int) -> set[int]:
    out = set()
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            out |= {int(c) for c in (task / "children").read_text().split()}
        except OSError:
            pass
    return out


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs Linux /proc to see the worker process")
def test_sigterm_stops_gsgs_sfm_and_its_pycolmap_worker(tmp_path):
    import time

    import cv2

    photos = tmp_path / "photos"
    photos.mkdir()
    rng = np.random.default_rng(0)
    base = cv2.GaussianBlur(rng.uniform(0, 255, (700, 900, 3)).astype(np.uint8), (0, 0), 2)
    for i in range(12):  # overlapping crops of one textured image: enough work to be stopped midway
        cv2.imwrite(str(photos / f"p{i:02d}.png"), base[20:660, 10 + 10 * i:650 + 10 * i])
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1]), "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "gsgs_engine", "sfm", str(photos), "--out", str(tmp_path / "out")],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        workers: set[int] = set()
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None and not workers:
            workers = {c for c in _children(proc.pid) if Path(f"/proc/{c}/cmdline").exists()}
            time.sleep(0.05)
        if proc.poll() is not None:
            pytest.skip("sfm finished before it could be interrupted")
        time.sleep(0.5)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130 and "interrupted" in err and "Traceback" not in err, err
    time.sleep(0.2)
    alive = [w for w in workers if Path(f"/proc/{w}").exists() and
             "zombie" not in Path(f"/proc/{w}/status").read_text().lower()]
    assert not alive, f"pycolmap worker(s) {alive} outlived gsgs sfm"


def test_world_scale_round_trip_covers_4d_motion():
    from gsgs_engine.io.ply import GaussianPly
    from gsgs_engine.io.world_scale import MOTION_PREFIX, ply_to_internal, ply_to_world
    from gsgs_engine.spacetime import PLY_MOTION

    assert all(name.startswith(MOTION_PREFIX) for name in PLY_MOTION)
    base = _splats(5)
    g = GaussianPly(base.positions, base.opacity_logits, base.log_scales, base.quats_wxyz, base.sh_dc, base.sh_rest,
                    extra={PLY_MOTION[0]: np.ones(5, np.float32), "t_center": np.full(5, 0.5, np.float32)})
    w = ply_to_world(g, 1e-3)
    assert np.allclose(w.positions, g.positions * 1e-3) and np.allclose(w.extra[PLY_MOTION[0]], 1e-3)
    assert np.allclose(w.extra["t_center"], 0.5) and np.allclose(w.log_scales, g.log_scales + np.log(1e-3))
    back = ply_to_internal(w, 1e-3)
    assert np.allclose(back.positions, g.positions, rtol=1e-6) and np.allclose(back.extra[PLY_MOTION[0]], 1.0)


@pytest.mark.parametrize("settings,expected", [({"max_image_size": 1e9}, "max_image_size must be at most 20000"),
                                               ({"single_camera": "yes"}, "single_camera must be true or false"),
                                               ([1, 2], "settings must be an object")])
def test_sfm_job_settings_are_validated(tmp_path, capsys, settings, expected):
    from gsgs_engine.job import Job

    job = Job.create(tmp_path / "job", "sfm", data={"photos": str(tmp_path)})
    spec = json.loads(job.spec_path.read_text())
    spec["settings"] = settings
    job.spec_path.write_text(json.dumps(spec))
    rc, _, err = gsgs(capsys, "run-job", job.root)
    assert rc == 2 and expected in error_line(err)


def test_a_job_resumes_only_with_the_settings_it_was_trained_with(scene, tmp_path, capsys):
    from gsgs_engine.job import Job

    settings = {"iters": 4, "sh_degree": 0, "init": "random", "random_init_points": 200}
    job = Job.create(tmp_path / "job", "train", data={"path": str(scene)}, settings=settings)
    assert gsgs(capsys, "run-job", job.root)[0] == 0
    spec = json.loads(job.spec_path.read_text())
    spec["settings"]["sh_degree"] = 1  # edited after the run: its checkpoint no longer matches
    job.spec_path.write_text(json.dumps(spec))
    rc, _, err = gsgs(capsys, "run-job", job.root)
    line = error_line(err)
    assert rc == 2 and "sh_degree: 0 in the checkpoint, 1 now" in line and "delete its checkpoints/ folder" in line
    assert job.status()["state"] == "error"


@pytest.mark.blender
def test_the_addon_refuses_to_import_nan_splats(tmp_path):
    bpy = pytest.importorskip("bpy")
    from gsgs_blender import splat_import

    from gsgs_engine import GsgsError
    from gsgs_engine.io.ply import write_gaussian_ply

    bpy.ops.wm.read_factory_settings(use_empty=True)
    write_gaussian_ply(tmp_path / "nan.ply", _splats(10, nan=True))
    try:
        with pytest.raises(GsgsError, match="nan.ply: 5 of 10 splats hold NaN or Inf"):
            splat_import.import_splats(tmp_path / "nan.ply")
        assert len(bpy.data.objects) == 0 and len(bpy.data.meshes) == 0  # nothing half-imported
    finally:
        bpy.ops.wm.read_factory_settings(use_empty=True)


def test_round_cameras_go_back_to_world_units():
    from gsgs_engine.io.world_scale import camera_dicts_to_internal, camera_dicts_to_world

    world = [{"name": "p", "t": [0.002, -0.004, 0.001], "near": 0.0001, "far": None, "fx": 50.0}]
    internal = camera_dicts_to_internal(world, 1e-3)
    assert internal[0]["t"] == pytest.approx([2.0, -4.0, 1.0]) and internal[0]["near"] == pytest.approx(0.1)
    back = camera_dicts_to_world(internal, 1e-3)
    assert back[0]["t"] == pytest.approx(world[0]["t"]) and back[0]["near"] == pytest.approx(1e-4)
    assert back[0]["fx"] == 50.0 and back[0]["far"] is None
    assert camera_dicts_to_world(world, 1.0) is world  # unscaled scenes: untouched
