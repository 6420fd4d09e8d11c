"""The benchmarks that were one-off scripts (issue 30): `gsgs bench mvs-points | dense-init | pseudo-targets`
are registered, answer --help, refuse bad inputs with one `gsgs: error:` line, and run on a tiny scene."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_train_cli import write_tiny_blender_scene

from gsgs_engine.cli import BENCHMARKS, main

REPO = Path(__file__).resolve().parents[1]
MOVED = {"mvs-points": "mvs_points", "dense-init": "dense_init", "pseudo-targets": "pseudo_targets"}


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    return write_tiny_blender_scene(tmp_path_factory.mktemp("moves") / "scene", n_train=3, n_test=2)


def gsgs(capsys, *args) -> tuple[int, str, str]:
    rc = main([str(a) for a in args])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def one_error_line(err: str) -> str:
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert "Traceback" not in err and len(lines) == 1 and lines[0].startswith("gsgs: error: "), err
    return lines[0]


def test_the_moved_benchmarks_are_registered_and_the_scripts_gone():
    for name, module in MOVED.items():
        assert BENCHMARKS[name][0] == f"gsgs_engine.bench.{module}"
    for script in ("mvs_check.py", "dense_init_compare.py", "pseudo_target_quality.py"):
        assert not (REPO / "scripts" / script).exists()


@pytest.mark.parametrize("name", sorted(MOVED))
def test_help_exits_0(name):
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.run([sys.executable, "-m", "gsgs_engine", "bench", name, "--help"], capture_output=True,
                          text=True, env=env, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert f"gsgs bench {name}" in proc.stdout


def test_the_moved_modules_import_without_torch():
    code = ("import sys\nimport gsgs_engine.bench.mvs_points, gsgs_engine.bench.dense_init, "
            "gsgs_engine.bench.pseudo_targets\nassert 'torch' not in sys.modules, 'torch imported'\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(REPO)}, timeout=120)
    assert proc.returncode == 0, proc.stderr


def test_mvs_points_refuses_missing_scenes_before_running(tmp_path, capsys):
    (tmp_path / "llff_flower").mkdir()
    rc, _, err = gsgs(capsys, "bench", "mvs-points", "--data-root", tmp_path, "--scenes", "llff_flower,llff_nowhere")
    assert rc == 2
    assert "llff_nowhere" in one_error_line(err) and "llff_flower" not in one_error_line(err)
    rc, _, err = gsgs(capsys, "bench", "mvs-points", "--data-root", tmp_path, "--scenes", ",")
    assert rc == 2 and "names no scene" in one_error_line(err)


def test_dense_init_bad_inputs_are_one_line(tmp_path, capsys):
    rc, _, err = gsgs(capsys, "bench", "dense-init", tmp_path / "nowhere", "--init", "sfm", "--out", tmp_path / "o")
    assert rc == 2 and "no such file or folder" in one_error_line(err)
    rc, _, err = gsgs(capsys, "bench", "dense-init", tmp_path, "--init", "mvs", "--out", tmp_path / "o", "--iters", 0)
    assert rc == 2 and "--iters must be at least 1" in one_error_line(err)
    assert not (tmp_path / "o").exists()


def test_dense_init_runs_a_tiny_cell(scene, tmp_path, capsys):
    rc, out, err = gsgs(capsys, "bench", "dense-init", scene, "--init", "mvs", "--out", tmp_path / "run",
                        "--iters", 3)
    assert rc == 0, err
    row = json.loads(out.strip().splitlines()[-1])
    assert set(row) >= {"init", "psnr", "ssim", "train_seconds", "num_gaussians", "init_seconds"}
    assert row["init"]["method"] in ("mvs", "mvs+fallback", "fallback")
    assert (tmp_path / "run" / "metrics.json").is_file() and (tmp_path / "run" / "point_cloud.ply").is_file()


def test_pseudo_targets_prints_the_table(scene, tmp_path, capsys):
    from gsgs_engine.io.ply import GaussianPly, write_gaussian_ply

    rng = np.random.default_rng(0)
    n = 200
    write_gaussian_ply(tmp_path / "model.ply", GaussianPly(
        rng.uniform(-0.7, 0.7, (n, 3)).astype(np.float32), np.full(n, 2.0), np.full((n, 3), -2.5),
        np.tile([1.0, 0, 0, 0], (n, 1)), rng.uniform(-1, 1, (n, 3)), np.zeros((n, 0, 3))))
    rc, out, err = gsgs(capsys, "bench", "pseudo-targets", scene, tmp_path / "model.ply", "--backend", "reference")
    assert rc == 0, err
    lines = out.strip().splitlines()
    assert lines[0].split() == ["view", "render", "dB", "target", "dB"]
    assert len(lines) == 2 + 2 and lines[-1].startswith("mean")  # header, the 2 test views, the mean
    assert all(np.isfinite(float(x)) for x in lines[-1].split()[1:])
