"""One cell of `gsgs bench accuracy`, run in its own process: plan, train, evaluate, report.

`python -m gsgs_engine.bench.accuracy_cell DATA --out DIR --settings JSON` writes DIR/cell.json
(the measured numbers) next to the usual training outputs (metrics.json, point_cloud.ply,
renders/). A cell trained at a reduced resolution is evaluated again on the full-resolution
test views, so every cell's PSNR compares against the same images.
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path

CELL_KEYS = ("iters", "resolution_scale", "max_side", "pseudo_views", "rounds", "sh_degree", "prior", "backend",
             "depth_reg")
DEFAULT_CELL = {"iters": 1000, "resolution_scale": 1.0, "max_side": 0, "pseudo_views": 8, "rounds": 2,
                "sh_degree": "auto", "prior": "auto", "backend": "auto", "depth_reg": True}


def normalise_cell(settings: dict) -> dict:
    """Complete a cell's settings with the defaults and check them (GsgsError naming the bad key)."""
    from gsgs_engine import GsgsError

    unknown = sorted(set(settings) - set(CELL_KEYS))
    if unknown:
        raise GsgsError(f"accuracy grid cell {settings}: unknown keys {unknown}; known: {', '.join(CELL_KEYS)}")
    cell = {**DEFAULT_CELL, **settings}
    if cell["prior"] not in ("none", "auto", "warp", "depth", "diffusion"):
        raise GsgsError(f"accuracy grid cell {settings}: prior must be none, auto, warp, depth or diffusion")
    if cell["prior"] in ("none", "depth"):
        cell["pseudo_views"], cell["rounds"] = 0, 0
    if not (isinstance(cell["iters"], int) and cell["iters"] >= 1):
        raise GsgsError(f"accuracy grid cell {settings}: iters must be a positive integer")
    if not (isinstance(cell["resolution_scale"], (int, float)) and 0 < cell["resolution_scale"] <= 1):
        raise GsgsError(f"accuracy grid cell {settings}: resolution_scale must be in (0, 1]")
    if not (isinstance(cell["max_side"], int) and cell["max_side"] >= 0):
        raise GsgsError(f"accuracy grid cell {settings}: max_side must be 0 (no cap) or a number of pixels")
    if cell["sh_degree"] != "auto" and cell["sh_degree"] not in (0, 1, 2, 3):
        raise GsgsError(f"accuracy grid cell {settings}: sh_degree must be auto or 0..3")
    if cell["backend"] not in ("auto", "reference", "cpu", "cuda"):
        raise GsgsError(f"accuracy grid cell {settings}: backend must be auto, reference, cpu or cuda")
    if not isinstance(cell["depth_reg"], bool):
        raise GsgsError(f"accuracy grid cell {settings}: depth_reg must be true or false")
    if cell["prior"] == "none":
        cell["depth_reg"] = True  # no prior, no depth term: one cell, not two
    cell["resolution_scale"] = float(cell["resolution_scale"])
    return cell


def overrides_for(cell: dict) -> dict:
    """Effect-plan overrides a cell pins (a cell measures its settings, not the plan's choice)."""
    out: dict = {}
    if cell["sh_degree"] != "auto":
        out["sh_degree"] = int(cell["sh_degree"])
    if cell["prior"] in ("auto", "warp", "diffusion"):
        out["pseudo_views"] = int(cell["pseudo_views"]) if cell["pseudo_views"] else "off"
    return out


def _full_resolution_eval(data: str, fmt: str, train_views, ply_path: Path, backend: str) -> dict:
    import torch

    from gsgs_engine.gaussians import GaussianModel
    from gsgs_engine.io import load_scene
    from gsgs_engine.io.ply import read_gaussian_ply
    from gsgs_engine.render import render
    from gsgs_engine.train.evaluate import evaluate_views

    from gsgs_engine.train.trainer import resolve_device

    scene = load_scene(data, format=fmt, train_views=train_views)
    device, _ = resolve_device(backend)  # the backend renders where the Gaussians live (gsplat: CUDA)
    from gsgs_engine.io.world_scale import ply_to_internal

    model = GaussianModel.from_ply(ply_to_internal(read_gaussian_ply(ply_path), scene.world_scale)).to(device)
    bg = torch.as_tensor(scene.background, dtype=torch.float32, device=device)
    deg = model.max_sh_degree

    def render_fn(cam):
        return render(model.means, model.quats, model.scales, model.opacities, model.sh(deg), cam, sh_degree=deg,
                      background=bg, backend=backend)

    return evaluate_views(render_fn, scene.test, renders_dir=None)


def run_cell(data: str, out: Path, cell: dict, train_views: int | None = None, fmt: str = "auto") -> dict:
    from gsgs_engine.reconstruct import train_with_effects
    from gsgs_engine.io import load_scene
    from gsgs_engine.job import write_json_atomic
    from gsgs_engine.priors.config import PriorConfig
    from gsgs_engine.train.trainer import TrainConfig, validate_config

    cell = normalise_cell(cell)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    scene = load_scene(data, format=fmt, train_views=train_views, resolution_scale=cell["resolution_scale"],
                       max_side=cell["max_side"])
    tc = TrainConfig(iters=cell["iters"], backend=cell["backend"], checkpoint_every=0)
    validate_config(tc)
    pc = PriorConfig(prior=cell["prior"], num_pseudo=max(int(cell["pseudo_views"]), 1), rounds=int(cell["rounds"]),
                     depth_reg=cell["depth_reg"])
    if cell["prior"] == "warp" and cell["depth_reg"]:
        pc.depth_source = "sparse"  # the ablation row "warp-inpaint + depth": the depth term, whatever auto would do
    plan = {"data": str(data), "format": scene.format, "resolution_scale": scene.resolution_scale,
            "bench_cell": cell}
    metrics = train_with_effects(scene, tc, pc, out, None, overrides=overrides_for(cell), plan=plan,
                                 log=lambda m: print(m, flush=True))
    wall = time.perf_counter() - t0
    evaluate_s = float(metrics.get("phase_seconds", {}).get("evaluate", 0.0))
    record = {"settings": cell, "seconds": round(wall - evaluate_s, 3), "wall_seconds": round(wall, 3),
              "train_seconds": round(float(metrics["train_seconds"]), 3), "psnr": metrics["psnr"],
              "ssim": metrics["ssim"], "lpips": metrics["lpips"], "lpips_reason": metrics.get("lpips_reason"),
              "num_gaussians": metrics["num_gaussians"], "iterations": metrics["iterations"],
              "phase_seconds": metrics.get("phase_seconds", {}), "effects": metrics["plan"].get("effects"),
              "eval_resolution": "full"}
    if scene.resolution_scale != 1.0:
        full = _full_resolution_eval(data, fmt, train_views, out / "point_cloud.ply", cell["backend"])
        record["at_train_resolution"] = {k: metrics[k] for k in ("psnr", "ssim", "lpips")}
        record.update({"psnr": full["psnr"], "ssim": full["ssim"], "lpips": full["lpips"],
                       "lpips_reason": full.get("lpips_reason")})
    # the cell's own peak; pycolmap runs in a grandchild, whose peak RUSAGE_CHILDREN reports
    record["ru_maxrss_self_kb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    record["ru_maxrss_children_kb"] = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    write_json_atomic(out / "cell.json", record)
    return record


def main(argv: list[str] | None = None) -> int:
    from gsgs_engine import GsgsError

    parser = argparse.ArgumentParser(prog="python -m gsgs_engine.bench.accuracy_cell", description=__doc__)
    parser.add_argument("data")
    parser.add_argument("--out", required=True)
    parser.add_argument("--settings", required=True, help="the cell as JSON (keys: " + ", ".join(CELL_KEYS) + ")")
    parser.add_argument("--train-views", type=int, default=None)
    parser.add_argument("--format", default="auto")
    args = parser.parse_args(argv)
    from gsgs_engine.allocator import keep_freed_memory

    keep_freed_memory()  # the cell trains as `gsgs train` does (the command line sets it)
    try:
        record = run_cell(args.data, Path(args.out), json.loads(args.settings), args.train_views, args.format)
    except GsgsError as exc:
        print(f"gsgs: error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps({k: record[k] for k in ("seconds", "psnr", "ssim", "num_gaussians")}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
