"""`gsgs bench dense-init`: plain 3DGS from the SfM points of the training views vs from the dense (MVS) init.

One cell per process: `gsgs bench dense-init SCENE --init sfm|mvs --out DIR [--iters 1000]
[--seed 0] [--train-views 3 | --train-ids r_2,...] [--resolution-scale S]`. Both cells run the same
train_and_export (same config, evaluation, metrics.json); only the initial Gaussians differ: "sfm" is
the trainer's SfM-point initialisation, "mvs" is TrainConfig(init="mvs"), for which train_and_export
builds the initial model with gsgs_engine.init.mvs.dense_initial_model (default MVSConfig). Prints one
JSON line: the init, the test metrics, the training and initialisation seconds.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", help="scene folder")
    parser.add_argument("--init", choices=["sfm", "mvs"], required=True,
                        help="sfm: the trainer's own initialisation; mvs: dense_initial_model")
    parser.add_argument("--out", type=Path, required=True, help="run folder (PLY, renders/, metrics.json)")
    parser.add_argument("--iters", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--train-views", type=int, default=None, help="as given to gsgs train (LLFF: 3)")
    parser.add_argument("--train-ids", type=str, default=None, help="comma-separated training view names")
    parser.add_argument("--resolution-scale", type=float, default=None)


def run(args: argparse.Namespace) -> int:
    from gsgs_engine import GsgsError

    if args.iters < 1:
        raise GsgsError(f"--iters must be at least 1 (got {args.iters})")
    if args.train_views is not None and args.train_views < 1:
        raise GsgsError(f"--train-views must be at least 1 (got {args.train_views})")
    from gsgs_engine.io.loader import load_scene
    from gsgs_engine.reconstruct import train_and_export
    from gsgs_engine.train.trainer import TrainConfig

    ids = args.train_ids.split(",") if args.train_ids else None
    scene = load_scene(args.scene, train_views=args.train_views, train_ids=ids, resolution_scale=args.resolution_scale)
    config = TrainConfig(iters=args.iters, seed=args.seed, init=args.init)
    metrics = train_and_export(scene, config, args.out, args.out / "checkpoints")
    keys = ("psnr", "ssim", "lpips_vgg", "lpips_alex", "train_seconds", "num_gaussians")
    print(json.dumps({"init": metrics["init"], **{k: metrics.get(k) for k in keys},
                      "init_seconds": metrics["phase_seconds"].get("init")}))
    return 0
