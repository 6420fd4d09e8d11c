"""`gsgs eval DIR --data DATA`: re-evaluate a trained result (DIR/point_cloud.ply) on the test views.

Reads the PLY only (not the checkpoints), so results from other 3DGS tools evaluate too.
Writes DIR/eval.json and prints PSNR / SSIM / LPIPS.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("result", help="folder with point_cloud.ply (a `gsgs train` output or a job's result/), "
                                       "or the PLY itself")
    parser.add_argument("--data", required=True, help="scene folder whose test views to evaluate on")
    from gsgs_engine.io.loader import FORMATS

    parser.add_argument("--format", default="auto", choices=list(FORMATS))
    parser.add_argument("--frames", default=None, metavar="IDS",
                        help="scenes with time: the frame ids the result was trained on (default: the ones "
                             "recorded in metrics.json, else all)")
    parser.add_argument("--split", default="test", help="split to evaluate (default test)")
    parser.add_argument("--backend", default="auto", choices=["auto", "cpu", "reference", "cuda"])
    parser.add_argument("--resolution-scale", type=float, default=None,
                        help="image scale (default: the one recorded in metrics.json, else 1)")
    bg = parser.add_mutually_exclusive_group()
    bg.add_argument("--white-background", dest="background", action="store_const", const="white")
    bg.add_argument("--black-background", dest="background", action="store_const", const="black")
    parser.add_argument("--renders", default=None, help="folder for the renders (default: none written)")


def _find_ply(result: Path) -> Path:
    from gsgs_engine import GsgsError

    if result.is_file():
        return result
    for candidate in (result / "point_cloud.ply", result / "result" / "point_cloud.ply"):
        if candidate.is_file():
            return candidate
    raise GsgsError(f"{result}: no point_cloud.ply here or in result/; pass a `gsgs train --out` folder or a PLY")


def run(args: argparse.Namespace) -> int:
    import torch

    from gsgs_engine import GsgsError
    from gsgs_engine.gaussians import GaussianModel
    from gsgs_engine.io import load_scene
    from gsgs_engine.io.ply import read_gaussian_ply
    from gsgs_engine.job import write_json_atomic
    from gsgs_engine.train.evaluate import evaluate_views
    from gsgs_engine.train.trainer import render_model, resolve_device

    from gsgs_engine.settings_schema import check_args

    check_args(args)
    ply_path = _find_ply(Path(args.result))
    recorded = {}
    metrics_path = ply_path.parent / "metrics.json"
    if metrics_path.is_file():
        try:
            recorded = json.loads(metrics_path.read_text()).get("plan", {})
        except (OSError, json.JSONDecodeError):
            recorded = {}
    scale = args.resolution_scale if args.resolution_scale is not None else float(recorded.get("resolution_scale", 1.0))
    if args.background is not None:
        background = (1.0, 1.0, 1.0) if args.background == "white" else (0.0, 0.0, 0.0)
    else:
        background = tuple(recorded.get("background", (1.0, 1.0, 1.0)))
    frames = args.frames if args.frames is not None else recorded.get("frames")
    scene = load_scene(args.data, format=args.format, resolution_scale=scale, background=background, frames=frames)
    views = scene.split(args.split)
    if not views:
        raise GsgsError(f"{args.data}: split {args.split!r} has no views to evaluate")
    device, _ = resolve_device(args.backend)  # the CUDA backend renders Gaussians that live on the GPU
    splats = read_gaussian_ply(ply_path)  # NaN / Inf values are refused here, naming the file
    if len(splats) == 0:
        raise GsgsError(f"{ply_path}: the PLY holds no Gaussians (0 vertices); nothing to evaluate: train again "
                        "or pass another result")
    from gsgs_engine.io.world_scale import ply_to_internal

    model = GaussianModel.from_ply(ply_to_internal(splats, scene.world_scale)).to(device)
    bg = torch.tensor(background, dtype=torch.float32, device=device)
    from gsgs_engine.render.project import DEFAULT_NEAR

    near = float(recorded.get("novel_view_near", DEFAULT_NEAR))  # the run's (an inward-shell rig's; else the default)
    sphere = None
    if recorded.get("background_sphere") and args.background is None:  # the run's learned wall behind the splats
        from gsgs_engine.train.background_sphere import BackgroundSphere

        sphere = BackgroundSphere.from_record(recorded["background_sphere"], ply_path.parent, scene.world_scale,
                                              device)

    def render_view(cam):
        out = render_model(model, cam, bg, args.backend, near=near)
        return out if sphere is None else sphere.composite(out, cam, bg)

    result = evaluate_views(render_view, views, renders_dir=Path(args.renders) if args.renders else None)
    result.update({"ply": str(ply_path), "data": str(args.data), "split": args.split, "backend": args.backend,
                   "resolution_scale": scale, "background": list(background), "num_gaussians": model.num_gaussians,
                   "near": near, "background_sphere": sphere is not None})
    if not all(math.isfinite(result[k]) for k in ("psnr", "ssim")):
        raise GsgsError(f"{ply_path}: evaluation gave PSNR {result['psnr']} / SSIM {result['ssim']} (not finite); "
                        "the renders hold NaN, so the result is damaged: retrain it")
    out_path = ply_path.parent / "eval.json"
    lp = f"{result['lpips']:.4f}" if result["lpips"] is not None else f"n/a ({result.get('lpips_reason')})"
    # the numbers first: a folder that cannot be written to must not cost the user the evaluation
    print(f"{len(views)} {args.split} views: PSNR {result['psnr']:.2f}  SSIM {result['ssim']:.4f}  LPIPS {lp}",
          flush=True)
    from gsgs_engine.write_errors import writing

    with writing(out_path, "eval.json"):
        write_json_atomic(out_path, result)
    print(f"written {out_path}", file=sys.stderr)
    return 0
