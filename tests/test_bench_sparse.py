"""`gsgs bench sparse`: statistics over seeds and scenes, variants, and a tiny real resumable run."""

from __future__ import annotations

import json

import pytest

from gsgs_engine import GsgsError
from gsgs_engine.bench.sparse import (BLENDER_TRAIN_IDS, cell_spec, load_variants, main, mean_std, summarise)
from tests.conftest import shared_scene


def record(scene: str, variant: str, seed: int, psnr: float, protocol: str = "llff") -> dict:
    return {"protocol": protocol, "scene": scene, "variant": variant, "seed": seed,
            "metrics": {"psnr": psnr, "ssim": 0.5, "lpips_vgg": 0.3, "lpips_alex": None, "train_seconds": 10.0,
                        "seconds": 12.0, "num_gaussians": 1000}}


def test_mean_and_sample_std():
    assert mean_std([1.0, 2.0, 3.0]) == (2.0, 1.0)
    assert mean_std([4.0]) == (4.0, 0.0)
    assert mean_std([1.0, None]) == (None, None) and mean_std([]) == (None, None)


def test_summary_per_scene_and_protocol_mean_over_complete_seeds():
    recs = [record("a", "v", 0, 20.0), record("a", "v", 1, 22.0), record("b", "v", 0, 16.0),
            record("b", "v", 1, 18.0), record("a", "v", 2, 30.0)]  # seed 2 lacks scene b: not in the mean row
    rows = {(r["scene"], r["variant"]): r for r in summarise(recs)}
    assert rows[("a", "v")]["psnr"] == mean_std([20.0, 22.0, 30.0]) and rows[("a", "v")]["seeds"] == [0, 1, 2]
    mean_row = rows[("mean", "v")]
    assert mean_row["seeds"] == [0, 1] and mean_row["psnr"] == mean_std([18.0, 20.0])
    assert mean_row["lpips_alex"] == (None, None)  # missing values are n/a, never a partial mean


def test_protocol_cells_and_variants(tmp_path):
    data, settings = cell_spec("blender", tmp_path, {"prior": "none", "iters": 500}, seed=2, iters=None,
                               resolution_scale=None)
    assert data["train_ids"] == BLENDER_TRAIN_IDS and "r_75" not in data["train_ids"]
    assert settings["resolution_scale"] == 0.5 and settings["background"] == [1.0, 1.0, 1.0]
    assert settings["seed"] == 2 and settings["iters"] == 500
    data, settings = cell_spec("llff", tmp_path, {}, seed=0, iters=20, resolution_scale=None)
    assert data["train_views"] == 3 and settings["resolution_scale"] == 1.0 and settings["iters"] == 20
    assert load_variants('{"x": {"prior": "none"}}') == {"x": {"prior": "none"}}
    with pytest.raises(GsgsError, match="--variants"):
        load_variants("[1, 2]")


@pytest.mark.slow
def test_tiny_real_run_is_resumable(tmp_path, capsys):
    root = shared_scene("blender_chair").parent
    argv = ["--protocol", "blender", "--scene", "blender_chair", "--seeds", "1", "--iters", "10",
            "--resolution-scale", "0.08", "--data-root", str(root), "--work", str(tmp_path / "work"),
            "--doc", str(tmp_path / "doc" / "sparse.md"), "--variants", '{"plain": {"prior": "none"}}']
    assert main(argv) == 0
    first = json.loads((tmp_path / "doc" / "sparse.json").read_text())
    cell = first["cells"][0]
    assert cell["metrics"]["psnr"] > 0 and cell["metrics"]["num_gaussians"] > 0
    # the machine the cell trained on, from its metrics.json, in the JSON and the table
    from gsgs_engine.machine import cpu_model

    assert cell["machine"].startswith(cpu_model()) and first["meta"]["cell_machines"] == [cell["machine"]]
    assert f"Cells trained on: {cell['machine']}." in (tmp_path / "doc" / "sparse.md").read_text()
    job = json.loads((tmp_path / "work" / "blender" / "blender_chair" / "plain" / "seed0" / "job.json").read_text())
    assert job["data"]["train_ids"] == BLENDER_TRAIN_IDS and job["settings"]["seed"] == 0
    table = (tmp_path / "doc" / "sparse.md").read_text()
    assert "| blender_chair | plain | 1 |" in table
    assert "Where a step's time goes" in table and "| blender_chair | plain | 0 |" in table  # the step profile
    capsys.readouterr()
    assert main(argv) == 0  # everything finished: nothing trains again
    assert "done before, skipped" in capsys.readouterr().out
    again = json.loads((tmp_path / "doc" / "sparse.json").read_text())
    assert again["cells"][0]["metrics"] == cell["metrics"]


def test_cell_seconds_never_undercount_the_loop_and_command_line_is_the_users():
    from gsgs_engine.bench.sparse import _own_arguments, cell_numbers

    # the horns auto cell of 2026-11-23: phases (but evaluate) sum to 307.3 s, the loop's clock says 314.3 s
    phases = {"init": 1.128, "render": 128.776, "backward": 161.739, "optimise": 8.73, "densify": 0.911,
              "checkpoint": 0.03, "evaluate": 15.42, "prior_render": 2.698, "prior_generate": 1.063, "plan": 2.299}
    numbers = cell_numbers({"phase_seconds": phases, "train_seconds": 314.3264, "psnr": 20.0})
    assert numbers["seconds"] == pytest.approx(314.3264 + 1.128 + 2.299)
    assert cell_numbers({"phase_seconds": {"plan": 1.0, "render": 50.0}, "train_seconds": 10.0})["seconds"] == 51.0
    assert cell_numbers({"train_seconds": 10.0})["seconds"] is None
    assert _own_arguments(["bench", "sparse", "--seeds", "1"]) == ["--seeds", "1"]
    assert _own_arguments(["--seeds", "1"]) == ["--seeds", "1"]


def test_seeds_take_a_count_a_range_or_a_list():
    import argparse

    from gsgs_engine.bench.sparse import parse_seeds

    assert parse_seeds("3") == [0, 1, 2]
    assert parse_seeds("1-2") == [1, 2] and parse_seeds("2-2") == [2]
    assert parse_seeds("2,1") == [1, 2] and parse_seeds("2,") == [2]
    for bad in ("0", "-1", "a", "3-1", "1,-2", ""):
        with pytest.raises(argparse.ArgumentTypeError, match="--seeds"):
            parse_seeds(bad)


def test_named_ablation_set_reuses_the_grid_cells_and_every_setting_passes_the_job_schema():
    from gsgs_engine.bench.sparse import ABLATION, VARIANTS
    from gsgs_engine.settings_schema import check_settings
    from gsgs_engine.train.techniques.catalogue import TECHNIQUES

    ablation = load_variants("ablation")
    assert ablation == ABLATION and load_variants("default") == VARIANTS
    # the grid's two variants under the same names and settings: their finished cells are not trained again
    assert all(ablation[name] == settings for name, settings in VARIANTS.items())
    alone = {t for s in ablation.values() for t in s.get("techniques", [])}
    assert alone == set(TECHNIQUES)  # every technique of the catalogue, each alone on the dense init
    for name, settings in ablation.items():
        assert check_settings(dict(settings), name) == settings
    with pytest.raises(GsgsError, match="named set: default, ablation"):
        load_variants("ablations")


def test_overview_lists_variants_in_order_with_the_change_against_the_first():
    from gsgs_engine.bench.sparse import overview

    recs = [record("llff_flower", "plain", s, 16.0 + s) for s in (0, 1)]
    recs += [record("llff_horns", "plain", s, 15.0) for s in (0, 1)]
    recs += [record("llff_flower", "best", s, 20.0) for s in (0, 1)] + [record("llff_horns", "best", 0, 19.0)]
    lines = overview(summarise(recs), "llff", ["plain", "best", "absent"])
    assert lines[0].startswith("| variant | seeds | llff_flower PSNR | llff_horns PSNR | PSNR | vs first |")
    plain, best = lines[2], lines[3]
    assert len(lines) == 4  # no line for a variant without cells
    assert plain.startswith("| plain | 2 | 16.50 ± 0.71 | 15.00 ± 0.00 | 15.75 ± 0.35 | +0.00 |")
    # one complete seed for "best" (horns ran seed 0 only): the over-scenes figure says 1 seed
    assert best.startswith("| best | 1 | 20.00 ± 0.00 | 19.00 | 19.50 | +3.75 |")  # one seed: no ± shown
    assert overview(summarise(recs), "blender", ["plain"]) == []


def test_report_only_trains_nothing_and_lists_the_cells_not_run(tmp_path, capsys):
    (tmp_path / "data" / "llff_horns").mkdir(parents=True)
    argv = ["--protocol", "llff", "--scene", "llff_horns", "--seeds", "2", "--report-only",
            "--data-root", str(tmp_path / "data"), "--work", str(tmp_path / "work"),
            "--doc", str(tmp_path / "doc.md"), "--variants", '{"plain": {"prior": "none"}}']
    assert main(argv) == 0
    assert not (tmp_path / "work").exists()  # no cell folder was even created
    report = json.loads((tmp_path / "doc.json").read_text())
    assert report["cells"] == [] and report["meta"]["not_run"] == ["llff/llff_horns/plain/seed 0",
                                                                   "llff/llff_horns/plain/seed 1"]
    assert "- llff/llff_horns/plain/seed 1" in (tmp_path / "doc.md").read_text()
    assert "2 not run" in capsys.readouterr().out


def test_step_profile_splits_the_loop_into_kernel_and_other_work():
    from gsgs_engine.bench.sparse import profile_lines, step_profile

    metrics = {"iterations": 100, "train_seconds": 20.0,
               "phase_seconds": {"render": 8.0, "backward": 10.0, "optimise": 1.0, "densify": 0.5},
               "kernel_seconds": {"project_forward": 0.5, "binning": 0.5, "raster_forward": 5.0, "backward_prep": 0.2,
                                  "raster_backward": 7.0, "backward_reduce": 0.3, "project_backward": 0.5},
               "technique_seconds": {"binocular": 3.0}}
    p = step_profile(metrics)
    assert p["raster fwd"] == pytest.approx(50.0) and p["raster bwd"] == pytest.approx(75.0)
    assert p["proj+SH"] == pytest.approx(10.0) and p["binning"] == pytest.approx(5.0)
    assert p["render+loss other"] == pytest.approx(20.0)  # 8 s render - 6 s of kernel forward, over 100 steps
    assert p["backward other"] == pytest.approx(20.0)  # 10 - 8
    assert p["step"] == pytest.approx(200.0) and p["technique:binocular"] == pytest.approx(30.0)
    assert step_profile({**metrics, "kernel_seconds": None}) is None  # an older build: no clocks, no row
    lines = profile_lines([{"scene": "s", "variant": "v", "seed": 0, "profile": p}, {"profile": None}])
    assert len(lines) == 5 and lines[-1].startswith("| s | v | 0 | 200 | 10.0 | 5.0 | 50.0 | 75.0 |")
