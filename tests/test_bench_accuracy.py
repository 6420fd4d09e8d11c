"""`gsgs bench accuracy`: grid, resumable results, Pareto front, table and plot; a real 2-cell run (slow)."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import pytest

from gsgs_engine import GsgsError
from gsgs_engine.bench import accuracy as ba
from gsgs_engine.bench.accuracy_cell import normalise_cell, overrides_for
from gsgs_engine.cameras import Camera, nerf_c2w_from_camera

SIZE = 24


def _look_at(eye, size=SIZE, fov_deg=50.0, name="") -> Camera:
    eye = np.asarray(eye, dtype=np.float64)
    f = -eye / np.linalg.norm(eye)
    r = np.cross(f, [0.0, 0.0, 1.0])
    r /= np.linalg.norm(r)
    R = np.stack([r, np.cross(f, r), f])
    focal = 0.5 * size / math.tan(math.radians(fov_deg) / 2)
    return Camera(R=R, t=-R @ eye, fx=focal, fy=focal, cx=size / 2, cy=size / 2, width=size, height=size, name=name)


def write_tiny_nerf(root: Path, n_train: int = 3, n_test: int = 2) -> Path:
    """A NeRF-synthetic folder whose images are renders of a few coloured Gaussians."""
    import cv2
    import torch

    from gsgs_engine.render import render

    g = torch.Generator().manual_seed(0)
    n = 30
    means, quats = (torch.rand(n, 3, generator=g) - 0.5) * 1.4, torch.randn(n, 4, generator=g)
    scales, opac = torch.rand(n, 3, generator=g) * 0.15 + 0.08, torch.full((n,), 0.9)
    sh = (torch.rand(n, 1, 3, generator=g) - 0.5) / 0.2820948
    for split, count, offset in (("train", n_train, 0.0), ("test", n_test, 0.5)):
        frames = []
        for i in range(count):
            a = offset + 2 * math.pi * i / count
            cam = _look_at((4 * math.cos(a), 4 * math.sin(a), 1.0))
            with torch.no_grad():
                img = render(means, quats, scales, opac, sh, cam, 0, torch.ones(3), backend="reference").color
            path = root / split / f"r_{i}.png"
            path.parent.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(path), (img.numpy()[..., ::-1] * 255 + 0.5).astype(np.uint8))
            frames.append({"file_path": f"./{split}/r_{i}", "transform_matrix": nerf_c2w_from_camera(cam).tolist()})
        (root / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": cam.fov_x, "frames": frames}))
    return root


# -- grid and cells ------------------------------------------------------------------------------------
def test_grids_are_valid_unique_and_cover_every_axis():
    small = ba.grid_cells("small")
    assert len(small) == 4 and len({ba.cell_id(c) for c in small}) == 4
    full = ba.grid_cells("full")
    ids = [ba.cell_id(c) for c in full]
    assert len(ids) == len(set(ids))
    for key in ("iters", "resolution_scale", "pseudo_views", "rounds", "sh_degree", "prior", "backend"):
        assert len({str(c[key]) for c in full}) >= 2, key


def test_cell_settings_are_checked_and_pinned_in_the_plan(tmp_path):
    with pytest.raises(GsgsError, match="unknown keys"):
        normalise_cell({"iterations": 5})
    with pytest.raises(GsgsError, match="resolution_scale"):
        normalise_cell({"resolution_scale": 2})
    plain = normalise_cell({"prior": "none", "pseudo_views": 8, "sh_degree": 0})
    assert (plain["pseudo_views"], plain["rounds"]) == (0, 0)
    assert overrides_for(plain) == {"sh_degree": 0}
    assert overrides_for(normalise_cell({"prior": "auto", "pseudo_views": 4})) == {"pseudo_views": 4}
    bad = tmp_path / "grid.json"
    bad.write_text("{not json")
    with pytest.raises(GsgsError, match="not valid JSON"):
        ba.grid_cells(str(bad))


def test_prior_grid_is_the_ablation_and_the_table_compares_with_none():
    cells = ba.grid_cells("prior")
    rows = [(c["prior"], c["depth_reg"]) for c in cells]
    assert rows == [("none", True), ("depth", True), ("warp", False), ("warp", True), ("auto", True)]
    assert len({ba.cell_id(c) for c in cells}) == 5 and ba.cell_id(cells[2]).endswith("_nodepth")
    with pytest.raises(GsgsError, match="depth_reg"):
        normalise_cell({"depth_reg": "no"})
    records = [_fake_record(c) for c in cells]
    records[2]["psnr"] = records[0]["psnr"] - 0.5
    table = ba.markdown_table(records, "ablation")
    assert "warp (no depth term)" in table
    assert "| -0.50 dB, 2.0x |" in table and "| +1.00 dB, 2.0x |" in table
    lone = _fake_record(normalise_cell({"prior": "auto", "iters": 300}))
    assert ba.versus_none(lone, [lone]) == "n/a"


# -- Pareto front ----------------------------------------------------------------------------------------
def test_pareto_front():
    pts = [(10.0, 20.0), (20.0, 19.0), (30.0, 25.0), (5.0, 18.0), (30.0, 24.0), (40.0, 25.0)]
    # (20, 19) is beaten by (10, 20); (30, 24) by (30, 25); (40, 25) by (30, 25) (slower, not better)
    assert ba.pareto_front(pts) == [3, 0, 2]
    assert ba.pareto_front([(1.0, 1.0), (1.0, 1.0)]) == [0, 1]  # ties dominate neither
    assert ba.pareto_front([]) == []


# -- resumability, table, plot (cells faked: no training) --------------------------------------------
def _fake_record(cell: dict) -> dict:
    seconds = cell["iters"] / 100 * (2.0 if cell["prior"] != "none" else 1.0)
    psnr = 15 + 2 * math.log10(cell["iters"]) + (1.0 if cell["prior"] != "none" else 0.0)
    return {"id": ba.cell_id(cell), "settings": cell, "status": "ok", "seconds": seconds, "psnr": psnr,
            "ssim": 0.5, "lpips": None, "lpips_reason": "no LPIPS weights", "num_gaussians": 1000,
            "peak_memory_mb": 300.0, "effects": {"sh_degree": {"value": 0}}}


def test_grid_resumes_and_writes_table_and_plot(tmp_path, monkeypatch):
    calls = []

    def fake_run(data, cell, cell_dir, train_views, fmt, timeout_s=None, python=None):
        calls.append(ba.cell_id(cell))
        if cell["iters"] == 300 and cell["prior"] == "auto" and len(calls) <= 4:
            return {"id": ba.cell_id(cell), "settings": cell, "status": "error", "error": "exit code 1: boom"}
        return _fake_record(cell)

    plots = []
    real_plot = ba.plot
    monkeypatch.setattr(ba, "run_cell_process", fake_run)
    builds = []
    monkeypatch.setattr(ba, "prepare_cpu_backend", lambda log=None: builds.append(1) or True)
    monkeypatch.setattr(ba, "plot", lambda records, path, title: plots.append(path) if plots else (
        plots.append(path), real_plot(records, path, title)))  # draw once: matplotlib is slow here
    cells = ba.grid_cells("small")
    data = tmp_path / "scene"
    data.mkdir()
    out = tmp_path / "bench"
    ba.run_grid(str(data), out, cells, log=lambda m: None)
    assert len(calls) == 4 and len(builds) == 1  # the CPU rasteriser is built before the cells, not in one
    table = (out / "accuracy_scene.md").read_text()
    assert "boom" in table and "| * |" in table and "LPIPS n/a: no LPIPS weights" in table
    assert (out / "accuracy_scene.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(plots) == 1  # the table after every cell, the plot once at the end

    # a second run re-runs only the failed cell; a third runs nothing
    ba.run_grid(str(data), out, cells, log=lambda m: None)
    assert calls[4:] == [ba.cell_id(cells[2])]
    ba.run_grid(str(data), out, cells, log=lambda m: None)
    assert len(calls) == 5 and len(builds) == 2  # nothing to run: nothing to build
    # a different number of training views is a different experiment: all cells run again
    ba.run_grid(str(data), out, cells[:1], train_views=2, log=lambda m: None)
    assert len(calls) == 6
    records = ba.read_results(out / "results.jsonl")
    assert len(records) == 6 and len(plots) == 4
    table = (out / "accuracy_scene.md").read_text()
    rows = [line for line in table.splitlines() if line.startswith("| ") and "it" in line.split("|")[3]]
    assert len(rows) == 4  # the newest ok record per cell
    front = [r.split("|")[3].strip() for r in rows if r.startswith("| * |")]
    pts = {r["id"]: (r["seconds"], r["psnr"]) for r in ba.latest_ok(records)}
    ids = list(pts)
    assert sorted(front) == sorted(ids[i] for i in ba.pareto_front([pts[k] for k in ids]))


def test_a_cut_line_in_results_is_ignored(tmp_path):
    path = tmp_path / "results.jsonl"
    path.write_text(json.dumps({"id": "a", "status": "ok"}) + "\n{\"id\": \"b\", \"sta")
    assert [r["id"] for r in ba.read_results(path)] == ["a"]


def test_command_lists_cells_and_rejects_missing_data(tmp_path, capsys):
    parser = argparse.ArgumentParser()
    ba.add_arguments(parser)
    args = parser.parse_args([str(tmp_path), "--out", str(tmp_path / "o"), "--list"])
    assert ba.run(args) == 0
    assert len(capsys.readouterr().out.split()) == 4
    args = parser.parse_args([str(tmp_path / "missing"), "--out", str(tmp_path / "o")])
    with pytest.raises(GsgsError, match="no such scene folder"):
        ba.run(args)


# -- the real thing: two cells trained in subprocesses -------------------------------------------------
@pytest.mark.slow
def test_two_cell_grid_end_to_end(tmp_path):
    data = write_tiny_nerf(tmp_path / "tiny")
    cells = [normalise_cell({"iters": it, "prior": "none", "sh_degree": 0, "backend": "auto"}) for it in (2, 6)]
    out = tmp_path / "bench"
    records = ba.run_grid(str(data), out, cells, log=lambda m: None)
    assert [r["status"] for r in records] == ["ok", "ok"], records
    for r in records:
        assert r["iterations"] == r["settings"]["iters"]
        assert math.isfinite(r["psnr"]) and 0 < r["ssim"] <= 1 and r["num_gaussians"] > 0
        assert r["peak_memory_mb"] > 50  # a Python process with torch loaded
        assert r["seconds"] > 0 and r["effects"]["sh_degree"]["value"] == 0
        assert r["effects"]["pseudo_views"]["enabled"] is False
        metrics = json.loads((out / "cells" / r["id"] / "metrics.json").read_text())
        assert metrics["plan"]["effects"]["sh_degree"]["source"] == "user"
    assert (out / "accuracy_tiny.png").is_file()
    before = (out / "results.jsonl").read_text()
    ba.run_grid(str(data), out, cells, log=lambda m: None)
    assert (out / "results.jsonl").read_text() == before  # nothing re-run


# -- presets ---------------------------------------------------------------------------------------------
def test_presets_are_grid_cells_measured_by_the_full_grid():
    from gsgs_engine.presets import PRESETS

    full = {ba.cell_id(c) for c in ba.grid_cells("full")}
    for name, p in PRESETS.items():
        cell = normalise_cell(p)
        assert ba.cell_id(cell) in full and ba.preset_of(cell) == name
    # ordered by cost: more iterations, never fewer pseudo views or rounds
    f, b, x = (PRESETS[n] for n in ("fast", "balanced", "best"))
    assert f["iters"] < b["iters"] < x["iters"] and f["pseudo_views"] <= b["pseudo_views"] <= x["pseudo_views"]


def test_apply_preset_fills_defaults_and_keeps_typed_flags():
    from gsgs_engine.priors.config import PriorConfig, add_prior_arguments
    from gsgs_engine.presets import add_preset_argument, apply_preset
    from gsgs_engine.train.trainer import TrainConfig

    parser = argparse.ArgumentParser()
    parser.add_argument("--iters", type=int, default=3000)
    parser.add_argument("--prior", default="none")
    parser.add_argument("--sh-degree", type=int, default=3)
    parser.add_argument("--backend", default="auto")
    parser.add_argument("--resolution-scale", type=float, default=1.0)
    add_prior_arguments(parser)
    add_preset_argument(parser)
    from gsgs_engine.presets import PRESETS

    defaults = vars(parser.parse_args([]))
    args = parser.parse_args(["--preset", "balanced", "--iters", "500"])
    changed = apply_preset(args, parser)
    b = PRESETS["balanced"]
    assert args.iters == 500 and args.prior == b["prior"] and args.rounds == b["rounds"]  # typed --iters wins
    expected = {dest: b[key] for key, dest in (("prior", "prior"), ("pseudo_views", "pseudo_views"), ("rounds", "rounds"))
                if defaults[dest] != b[key]}
    assert changed == expected
    assert args.effects_overrides == ({"pseudo_views": "off"} if b["prior"] == "none" else {})
    args = parser.parse_args(["--preset", "fast"])
    apply_preset(args, parser)
    assert (args.iters, args.prior, args.sh_degree) == (300, "auto", 3)  # SH: the plan decides
    assert args.effects_overrides == {}
    argv = ["--preset", "fast", "--sh-degree", "1", "--prior", "none"]
    args = parser.parse_args(argv)
    args._argv = argv  # as gsgs_engine.cli.main records it: a typed default still wins
    apply_preset(args, parser)
    assert (args.iters, args.prior, args.sh_degree) == (300, "none", 1)  # typed flags win
    assert args.effects_overrides == {}  # the preset's own overrides: a typed --prior none plans no pseudo views itself
    argv = ["--preset", "balanced", "--prior=none"]
    args = parser.parse_args(argv)
    args._argv = argv
    apply_preset(args, parser)
    assert (args.iters, args.prior) == (PRESETS["balanced"]["iters"], "none")
    assert apply_preset(parser.parse_args([]), parser) == {}
    tc, pc, eff, scale = apply_preset((TrainConfig(), PriorConfig()), name="best")
    x = PRESETS["best"]
    assert (tc.iters, pc.prior, pc.rounds, scale) == (x["iters"], x["prior"], x["rounds"], x["resolution_scale"])
    assert pc.num_pseudo == max(x["pseudo_views"], 1)
    assert eff == ({"pseudo_views": "off"} if x["prior"] == "none" else {})
    with pytest.raises(GsgsError, match="choose one of"):
        apply_preset((TrainConfig(), PriorConfig()), name="ultra")
