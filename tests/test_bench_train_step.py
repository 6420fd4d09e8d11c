"""`gsgs bench train-step`: the synthetic fixed-size model, one real cell per backend, the tables."""

from __future__ import annotations

import math

import pytest
import torch

from gsgs_engine.bench import train_step
from gsgs_engine.render import cpu_backend

from conftest import shared_scene


@pytest.fixture(scope="module")
def flower():
    path = shared_scene("llff_flower")
    if not cpu_backend.available():
        pytest.skip(f"compiled CPU kernel unavailable: {cpu_backend.unavailable_reason()}")
    return path


def test_synthetic_model_has_exactly_n_gaussians_in_the_init_box(flower):
    from gsgs_engine.gaussians import scene_bounds_from_cameras
    from gsgs_engine.io.loader import load_scene

    scene = load_scene(flower, train_views=3)
    model = train_step.synthetic_model(scene, scene.train, 1234, seed=1)
    assert model.num_gaussians == 1234 and model.active_sh_degree == 3 and model.all_finite()
    lo, hi = scene_bounds_from_cameras([v.camera for v in scene.train], scene.near, scene.far)
    means = model.means.detach()
    assert torch.all(means >= torch.as_tensor(lo, dtype=torch.float32) - 1e-4)
    assert torch.all(means <= torch.as_tensor(hi, dtype=torch.float32) + 1e-4)
    again = train_step.synthetic_model(scene, scene.train, 1234, seed=1)
    assert torch.equal(again.means, model.means)  # both backends of a row train the same model


@pytest.mark.parametrize("backend", ["cpu", "cpu_legacy"])
def test_one_cell_measures_a_profile(flower, backend):
    row = train_step.run_cell("flower", str(flower.parent), 1500, backend, steps=1, warmup=1, threads=1, seed=0)
    assert row["gaussians"] == row["gaussians_after"] == 1500 and (row["width"], row["height"]) == (504, 378)
    assert row["step_ms_min"] > 0 and row["loss_alone_ms"] > 0
    p = row["profile_ms"]
    assert set(p) == set(train_step.PHASES) and all(math.isfinite(v) for v in p.values())
    assert p["raster_fwd"] > 0 and p["raster_bwd"] > 0 and p["optimiser"] > 0
    if backend == "cpu":
        assert p["proj_fwd"] > 0 and p["proj_bwd"] > 0
    else:  # the torch projection is part of the torch phases
        assert p["proj_fwd"] == 0 and p["proj_bwd"] == 0


def test_tables_name_the_ratio_and_failures():
    rows = [
        {"scene": "flower", "gaussians": 10, "backend": "cpu_legacy", "step_ms_median": 30.0, "step_ms_min": 20.0,
         "profile_ms": {k: 1.0 for k in train_step.PHASES}, "loss_alone_ms": 2.0},
        {"scene": "flower", "gaussians": 10, "backend": "cpu", "step_ms_median": 10.0, "step_ms_min": 10.0,
         "profile_ms": {k: float("nan") for k in train_step.PHASES}, "loss_alone_ms": 2.0},
        {"scene": "lego", "gaussians": 10, "backend": "cpu", "error": "boom"},
    ]
    text = train_step.markdown_tables(rows, ["cpu_legacy", "cpu"])
    assert "| flower | 10 | 30.0 / 20.0 | 10.0 / 10.0 | 3.00x / 2.00x |" in text
    assert "lego N=10 cpu: failed: boom" in text
    assert "| - |" in text  # a pinned older build without the kernel's clocks


def test_bad_arguments_are_named(tmp_path):
    import argparse

    from gsgs_engine import GsgsError

    parser = argparse.ArgumentParser()
    train_step.add_arguments(parser)
    with pytest.raises(GsgsError, match="--scenes"):
        train_step.run(parser.parse_args(["--scenes", "nowhere"]))
    with pytest.raises(GsgsError, match="--data"):
        train_step.run(parser.parse_args(["--data", str(tmp_path)]))
    with pytest.raises(GsgsError, match="not a gsgs checkout"):
        train_step.run(parser.parse_args(["--data", str(shared_scene("llff_flower").parent), "--scenes", "flower",
                                          "--backends", f"cpu@{tmp_path}"]))
