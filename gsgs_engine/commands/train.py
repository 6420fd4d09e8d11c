"""`gsgs train DATA --out DIR`: train a Gaussian-splat scene from sparse views.

DIR is a job-like folder: progress.jsonl, status.json, log.txt, checkpoints/, and the
results point_cloud.ply, renders/ and metrics.json.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path



def add_arguments(parser: argparse.ArgumentParser) -> None:
    from gsgs_engine.train.trainer import DEFAULT_ITERS

    parser.add_argument("data", help="scene folder (NeRF-synthetic, LLFF, COLMAP, photos after sfm, or a job folder)")
    parser.add_argument("--out", required=True, help="output folder (results, progress.jsonl, checkpoints/)")
    from gsgs_engine.io.loader import FORMATS

    parser.add_argument("--format", default="auto", choices=list(FORMATS))
    parser.add_argument("--train-split", default=None, help="split to train on (e.g. 'dense' for lego_200)")
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--train-views", type=int, default=None, help="train on N views spread over the train split")
    group.add_argument("--train-ids", default=None, help="comma-separated view ids/names to train on")
    parser.add_argument("--frames", default=None, metavar="IDS",
                        help="scenes with time (multi-view video): frame ids to train and test on, e.g. 0 (one "
                             "frame: a static model), 0-9 or 0,5,9; times are renormalised over them (default: all)")
    parser.add_argument("--iters", type=int, default=DEFAULT_ITERS, help=f"optimisation steps (default {DEFAULT_ITERS})")
    parser.add_argument("--backend", default="auto", choices=["auto", "cpu", "reference", "cuda"])
    parser.add_argument("--prior", default="none",
                        help="generative prior: none (plain 3DGS, the default), depth, warp, diffusion or auto "
                             "(see gsgs_engine.priors.config)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--resolution-scale", type=float, default=1.0, help="image scale factor, e.g. 0.5")
    parser.add_argument("--max-side", type=int, default=0, metavar="PX",
                        help="train on views at most PX pixels on their longer side, after --resolution-scale "
                             "(default 0: no cap; the presets set one, see gsgs_engine.presets)")
    parser.add_argument("--sh-degree", type=int, default=None,
                        help="maximum SH degree 0..3 (default: the effect plan measures view dependence)")
    parser.add_argument("--checkpoint-every", type=int, default=500, help="steps between checkpoints (0 = only on exit)")
    parser.add_argument("--resume", action="store_true", help="continue from the newest checkpoint in OUT/checkpoints")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace the run already in OUT (its checkpoints, results, renders, progress)")
    parser.add_argument("--init", default="auto", choices=["auto", "sfm", "points", "random", "mvs"],
                        help="initial Gaussians: SfM of the training views, the source's points, random, or mvs "
                             "(dense multi-view stereo of the training views plus their SfM points)")
    parser.add_argument("--init-points", type=int, default=None,
                        help="number of random Gaussians when there are too few SfM points (default 5000)")
    parser.add_argument("--mvs-size", type=int, default=None,
                        help="--init mvs: longest side (px) of the images the plane sweep works on (default 256; "
                             "reduced further to keep the sweep within its budget)")
    parser.add_argument("--mvs-flow", choices=("off", "dis", "deepflow"), default="off",
                        help="--init mvs: also triangulate dense optical-flow matches between the training views "
                             "(OpenCV DIS or DeepFlow, forward-backward checked) and fuse them with the stereo points "
                             "(default %(default)s)")
    parser.add_argument("--coarse-fraction", type=float, default=0.0,
                        help="coarse-to-fine: the first FRACTION of the steps render the training views at "
                             "--coarse-scale of their size (default %(default)s: off)")
    parser.add_argument("--coarse-scale", type=float, default=0.5,
                        help="coarse-to-fine: render scale of those first steps (default %(default)s)")
    parser.add_argument("--position-lr-scale", type=float, default=None,
                        help="the Gaussians' position learning rate as a multiple of 3DGS's schedule (default: "
                             "the effect plan's; --prior auto raises it on object orbits and videos, else 1)")
    parser.add_argument("--attribute-lr-scale", type=float, default=None,
                        help="the colour, scale and rotation learning rates as one multiple of 3DGS's (default: the "
                             "effect plan's; --prior auto raises them on sparse object orbits below 3000 steps, "
                             "else 1)")
    parser.add_argument("--random-background", action="store_true",
                        help="a random background colour each step: RGBA scenes composite the target on the same "
                             "(alpha learned), RGB scenes keep the photo (every pixel learned opaque; "
                             "= --effects background=opaque)")
    bg = parser.add_mutually_exclusive_group()
    bg.add_argument("--white-background", dest="background", action="store_const", const="white")
    bg.add_argument("--black-background", dest="background", action="store_const", const="black")
    parser.set_defaults(background="white")
    from gsgs_engine.effect_plan import add_effects_argument
    from gsgs_engine.priors.config import add_prior_arguments
    from gsgs_engine.presets import add_preset_argument

    add_prior_arguments(parser)
    add_preset_argument(parser)
    add_effects_argument(parser)
    from gsgs_engine.cluster.submit import add_ray_arguments

    add_ray_arguments(parser)
    # what metrics.json records as the data: a run on a Ray worker trains a copy sent to it
    parser.add_argument("--data-label", default=None, help=argparse.SUPPRESS)
    parser.set_defaults(_parser=parser)


def _resume_command(args: argparse.Namespace) -> str:
    argv = [a for a in sys.argv[1:] if a != "--resume"]
    if not argv or argv[0] != "train":
        argv = ["train", str(args.data), "--out", str(args.out)]
    return "gsgs " + " ".join(shlex.quote(a) for a in argv) + " --resume"


def run(args: argparse.Namespace) -> int:
    from gsgs_engine import GsgsError
    from gsgs_engine.io import load_scene
    from gsgs_engine.job import Job
    from gsgs_engine.effect_plan import overrides_from_args
    from gsgs_engine.presets import apply_preset
    from gsgs_engine.priors.config import PRIOR_CHOICES, prior_config_from_args
    from gsgs_engine.reconstruct import train_with_effects
    from gsgs_engine.train.trainer import (TrainConfig, TrainingCancelled, TrainingInterrupted, resolve_device,
                                           validate_config)

    preset_changed = apply_preset(args, getattr(args, "_parser", None)) if args.preset else {}
    from gsgs_engine.settings_schema import check_args

    check_args(args)  # types, ranges, finiteness of every numeric flag (the rules job.json settings meet)
    if args.ray:
        from gsgs_engine.cluster.address import check_address

        check_address(args.ray)  # a non-loopback cluster without a token: refused before anything is read or sent
    if args.prior not in PRIOR_CHOICES:
        raise GsgsError(f"--prior {args.prior!r} is not available; choose one of: {', '.join(PRIOR_CHOICES)}")
    from gsgs_engine.train.techniques.catalogue import make_techniques, parse_techniques

    make_techniques(parse_techniques(args.techniques))  # unknown names / options stop before any data is read
    if args.resolution_scale <= 0:
        raise GsgsError(f"--resolution-scale must be positive (got {args.resolution_scale})")
    config = TrainConfig(iters=args.iters, sh_degree=3 if args.sh_degree is None else args.sh_degree,
                         backend=args.backend, seed=args.seed,
                         checkpoint_every=args.checkpoint_every, random_background=args.random_background,
                         init=args.init, coarse_fraction=args.coarse_fraction, coarse_scale=args.coarse_scale,
                         position_lr_scale=args.position_lr_scale, attribute_lr_scale=args.attribute_lr_scale)
    if args.mvs_size is not None:
        config.mvs_max_side = args.mvs_size
    config.mvs_flow = args.mvs_flow
    if args.init_points is not None:
        if args.init_points < 1:
            raise GsgsError(f"--init-points must be at least 1 (got {args.init_points})")
        config.random_init_points = args.init_points
    validate_config(config)
    if not args.ray:  # on a cluster the worker's devices count; it checks them itself
        resolve_device(config.backend)  # --backend cuda without CUDA / gsplat stops here, before any data is read
    out = Path(args.out)
    job = Job(root=out, spec={"task": "train"})  # a job-like folder; job.json is written only by Job.create
    from gsgs_engine.run_folder import claim_run_folder
    from gsgs_engine.train.checkpoint import latest_checkpoint

    claim_run_folder(out, args.resume, args.overwrite, latest_checkpoint(out / "checkpoints") is not None)
    from gsgs_engine.write_errors import writing

    with writing(out, "the output folder (--out)"):
        out.mkdir(parents=True, exist_ok=True)
    if args.ray:
        from gsgs_engine.cluster.submit import train_on_cluster

        return train_on_cluster(args, getattr(args, "_argv", None) or sys.argv[1:], out, _resume_command(args))
    job.set_status("running", f"training {args.data_label or args.data}")
    try:
        background = (1.0, 1.0, 1.0) if args.background == "white" else (0.0, 0.0, 0.0)
        train_ids = [s.strip() for s in args.train_ids.split(",") if s.strip()] if args.train_ids else None
        scene = load_scene(args.data, format=args.format, train_split=args.train_split,
                           train_views=args.train_views, train_ids=train_ids,
                           resolution_scale=args.resolution_scale, background=background, frames=args.frames,
                           max_side=args.max_side)
        plan = {"data": args.data_label or str(args.data), "format": scene.format or args.format, "train_split": args.train_split,
                "frames": args.frames, "resolution_scale": scene.resolution_scale, "max_side": args.max_side or None,
                "prior": args.prior, "preset": args.preset,
                "preset_changed": preset_changed}
        overrides = overrides_from_args(args)
        if args.random_background:
            overrides["background"] = "random"
        metrics = train_with_effects(scene, config, prior_config_from_args(args), out, out / "checkpoints",
                                     overrides=overrides, job=job, resume=args.resume, plan=plan)
    except TrainingInterrupted as exc:
        msg = (f"interrupted at step {exc.step}; checkpoint {exc.checkpoint}; resume with: {_resume_command(args)}")
        job.set_status("cancelled", msg)
        print(f"gsgs: {msg}", file=sys.stderr)
        return exc.exit_code
    except TrainingCancelled as exc:
        msg = f"cancelled at step {exc.step}; resume with: {_resume_command(args)}"
        job.set_status("cancelled", msg)
        print(f"gsgs: {msg}", file=sys.stderr)
        return 130
    except KeyboardInterrupt:  # Ctrl-C / SIGTERM while loading, planning or evaluating (outside the steps)
        msg = f"interrupted outside the training steps; resume with: {_resume_command(args)}"
        job.set_status("cancelled", msg)
        print(f"gsgs: {msg}", file=sys.stderr)
        return 130
    except GsgsError as exc:
        job.set_status("error", str(exc))
        raise
    except BaseException as exc:
        job.set_status("error", f"{type(exc).__name__}: {exc}")
        raise
    summary = (f"done: {metrics['iterations']} steps, {metrics['num_gaussians']} Gaussians, "
               f"{metrics['train_seconds']:.0f} s")
    if metrics["psnr"] is not None:
        summary += f", test PSNR {metrics['psnr']:.2f} SSIM {metrics['ssim']:.4f}"
    job.set_status("ok", summary)
    print(f"gsgs: {summary}; results in {out}", file=sys.stderr)
    return 0
