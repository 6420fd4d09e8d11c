"""Plain 3DGS from the SfM points of the training views vs from the dense (MVS) initialisation.

One cell per process: `python scripts/dense_init_compare.py SCENE --init sfm|mvs --out DIR [--iters 1000]
[--seed 0] [--train-views 3 | --train-ids r_2,...] [--resolution-scale S]`. Both cells run the same
train_and_export (same config, evaluation, metrics.json); only the initial Gaussians differ: for "mvs"
the trainer's initialiser is replaced by gsgs_engine.init.mvs.dense_initial_model.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("scene")
    parser.add_argument("--init", choices=["sfm", "mvs"], required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--iters", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--train-views", type=int, default=None)
    parser.add_argument("--train-ids", type=str, default=None)
    parser.add_argument("--resolution-scale", type=float, default=None)
    args = parser.parse_args()

    from gsgs_engine.io.loader import load_scene
    from gsgs_engine.train import trainer as trainer_module
    from gsgs_engine.reconstruct import train_and_export
    from gsgs_engine.train.trainer import TrainConfig

    ids = args.train_ids.split(",") if args.train_ids else None
    scene = load_scene(args.scene, train_views=args.train_views, train_ids=ids, resolution_scale=args.resolution_scale)
    config = TrainConfig(iters=args.iters, seed=args.seed, init="sfm")
    if args.init == "mvs":
        from gsgs_engine.init.mvs import dense_initial_model

        def mvs_init(scene, train_views, config, generator, log=print):
            return dense_initial_model(scene, train_views, config.sh_degree, seed=config.seed, log=log)

        trainer_module.initialise_gaussians = mvs_init
    metrics = train_and_export(scene, config, args.out, args.out / "checkpoints")
    keys = ("psnr", "ssim", "lpips_vgg", "lpips_alex", "train_seconds", "num_gaussians")
    print(json.dumps({"init": metrics["init"], **{k: metrics.get(k) for k in keys},
                      "init_seconds": metrics["phase_seconds"].get("init")}))


if __name__ == "__main__":
    main()
