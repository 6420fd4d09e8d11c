"""`gsgs bench dynamic --cameras 3,6,9 --out DIR [--data DIR]`: 4D vs two static baselines on the same views.

Without --data it renders the project's animated Blender scene (gsgs_blender.dynamic_scene; reused
when a matching render is in DIR/scene) and holds out camera 0. With --data it takes any multi-view
video the loaders read: a CMU Panoptic capture (io.panoptic: train on N of its 27 training cameras,
test on its 4 test cameras at every frame) or a scene in the dynamic layouts (io.dynamic). For each
N of --cameras it trains on N cameras at every frame and evaluates each model on the test views:
  4d               one SpacetimeModel over all frames (rendered at each view's time)
  static_all       one 3D model over all frames (time ignored)
  static_per_frame one 3D model per frame, trained on that frame's N views
PSNR / SSIM / LPIPS (VGG) are averaged over the test views (every test camera at every frame), and
PSNR inside the dynamic region beside them (bench.dynamic_region: foreground masks, or the pixels
that change over time), so a model that freezes the moving people cannot hide behind the static
background. train_seconds is the training loop's wall time (per-frame: summed over frames). Writes
DIR/results.json (one entry per camera count) and prints a table per count.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
import time
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
VARIANTS = ("4d", "static_all", "static_per_frame")


def add_arguments(parser) -> None:
    parser.add_argument("--cameras", default="3",
                        help="training cameras, one count or several: 3,6,9 (the paper's protocol; default 3)")
    parser.add_argument("--out", required=True, help="output folder (results.json, renders, the rendered scene)")
    parser.add_argument("--data", default=None, help="a multi-view video to use instead of rendering one: a Panoptic "
                                                      "capture or a dynamic scene folder (default: DIR/scene, "
                                                      "rendered when missing)")
    parser.add_argument("--ring", type=int, default=10, help="cameras in the rendered ring (camera 0 is held out)")
    parser.add_argument("--frames", type=int, default=10,
                        help="frames rendered / used (a Panoptic capture: N frames from --first-frame)")
    parser.add_argument("--first-frame", type=int, default=0,
                        help="a Panoptic capture's first frame id used (default 0): another time window of the "
                             "same capture, e.g. 10 with --frames 10 for frames 10-19")
    parser.add_argument("--resolution-scale", type=float, default=1.0, help="image scale of --data's views")
    parser.add_argument("--no-lpips", action="store_true",
                        help="skip LPIPS (about 7 s a 640x360 view on a 2-core CPU): for screening runs")
    parser.add_argument("--size", type=int, default=64, help="rendered image size in pixels (square)")
    parser.add_argument("--samples", type=int, default=4, help="Cycles samples per pixel")
    parser.add_argument("--iters", type=int, default=600, help="training steps of the 4D and static_all models")
    parser.add_argument("--per-frame-iters", type=int, default=200, help="training steps of each per-frame model")
    parser.add_argument("--init", default="random", choices=("random", "auto", "mvs"),
                        help="random (default, same box for every model), auto (triangulate, per frame for 4D) or "
                             "mvs (dense plane-sweep stereo plus the triangulated points, per frame for 4D)")
    parser.add_argument("--init-points", type=int, default=2000, help="random initial Gaussians")
    parser.add_argument("--sh-degree", type=int, default=0)
    parser.add_argument("--backend", default="auto", choices=("auto", "reference", "cpu", "cuda"))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--rig", default="auto", choices=("auto", "inward", "orbit"),
                        help="auto (default): read the rig from the first frame's training views as gsgs train does, "
                             "and draw the test views of an inward shell with its near plane; inward / orbit: say "
                             "what it is (gsgs train --effects rig=...); orbit keeps the renderer's default near plane")
    parser.add_argument("--techniques", default=None,
                        help="sparse-view techniques for every model of the comparison, as gsgs train takes them "
                             "(e.g. exposure,dropout; default none)")
    parser.add_argument("--background", default="fixed", choices=("fixed", "mean", "opaque", "sphere"),
                        help="every model's background: fixed (the scene's), mean (the training photos' mean colour, "
                             "in training and evaluation), opaque (a random colour behind each training step's "
                             "render, the photo unchanged; evaluated on the scene's) or sphere (a texture learned on "
                             "the sphere through the cameras, starting from the photos' mean colour: what gsgs train "
                             "--prior auto uses on an inward shell's RGB views)")
    parser.add_argument("--models", default=",".join(VARIANTS),
                        help=f"which of {', '.join(VARIANTS)} to train (default all; one model screens a 4D variant)")
    parser.add_argument("--position-lr-scale", type=float, default=1.0,
                        help="every model's position learning rate as a multiple of 3DGS's schedule (default "
                             "%(default)s; gsgs train --prior auto uses 3 on a video: effect_plan.POSITION_LR_SCALE)")
    parser.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: torch's default)")


def render_scene(data_dir: Path, ring: int, frames: int, size: int, samples: int) -> None:
    """Render the validation scene in a child process (gsgs_engine never imports bpy itself)."""
    if importlib.util.find_spec("bpy") is None:
        from gsgs_engine import GsgsError

        raise GsgsError(f"{data_dir}: no rendered dynamic scene and this Python has no bpy module; render it with "
                        f"`python -m gsgs_blender.dynamic_scene {data_dir}` where bpy is installed, or pass --data")
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO_ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    cmd = [sys.executable, "-m", "gsgs_blender.dynamic_scene", str(data_dir), "--cameras", str(ring),
           "--frames", str(frames), "--size", str(size), "--samples", str(samples)]
    proc = subprocess.run(cmd, env=env, cwd=str(REPO_ROOT), capture_output=True, text=True)
    if proc.returncode != 0:
        from gsgs_engine import GsgsError

        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        raise GsgsError(f"{data_dir}: rendering the dynamic scene failed ({' | '.join(tail)})")


def _subscene(scene, train_idx: list[int], test_idx: list[int]):
    """A Scene with only the given views (train / test splits), sharing the View objects."""
    from gsgs_engine.io.scene import Scene

    keep = sorted(set(train_idx) | set(test_idx))
    pos = {old: new for new, old in enumerate(keep)}
    return Scene(views=[scene.views[i] for i in keep],
                 splits={"train": [pos[i] for i in train_idx], "test": [pos[i] for i in test_idx]},
                 source=scene.source, format=scene.format, background=scene.background, near=scene.near,
                 far=scene.far, has_alpha=scene.has_alpha, world_scale=scene.world_scale)


def _static_mvs_model(trainer):
    """(initial_model, init_info) of a static baseline with --init mvs: the dense init gsgs train makes for a
    still (the 4D trainer makes its per-frame one itself)."""
    from gsgs_engine.init.mvs import trainer_dense_init

    return trainer_dense_init(trainer, log=lambda msg: None)


def _train_eval(trainer, test_views, renders_dir: Path | None, log, label: str, region_fn=None,
                lpips: bool = True, techniques=None) -> dict:
    from gsgs_engine.train.evaluate import evaluate_views
    from gsgs_engine.train.techniques.catalogue import make_techniques

    from gsgs_engine.train.dynamic import SpacetimeTrainer

    if trainer.config.init == "mvs" and not isinstance(trainer, SpacetimeTrainer):
        model, info = _static_mvs_model(trainer)
        trainer.setup(initial_model=model, init_info=info)
    else:
        trainer.setup()
    for technique in make_techniques(techniques or []):
        trainer.add_technique(technique)
    trainer.train()
    ev = evaluate_views(lambda cam: trainer.render(cam, sh_degree=trainer.model.max_sh_degree), test_views,
                        renders_dir=renders_dir, region_fn=region_fn, lpips=lpips,
                        max_renders=len(test_views))  # every test view: the comparison picture picks three times
    region = ev.get("psnr_region")
    log(f"[bench dynamic] {label}: {trainer.step} steps, {trainer.train_seconds:.1f}s, "
        f"{trainer.model.num_gaussians} Gaussians, held-out PSNR {ev['psnr']:.2f}"
        + (f", dynamic region {region:.2f}" if region is not None else ""))
    return {"psnr": ev["psnr"], "ssim": ev["ssim"], "lpips": ev["lpips"], "psnr_region": region,
            "psnr_outside": ev.get("psnr_outside"),
            "techniques": {t.name: t.report() for t in trainer.techniques},
            "train_seconds": trainer.train_seconds, "iters": trainer.step,
            "num_gaussians": trainer.model.num_gaussians, "init": trainer.init_info.to_dict(),
            "per_view": [{"name": v["name"], "time": t.camera.time, "psnr": v["psnr"], "ssim": v["ssim"],
                          "lpips": v["lpips"], "psnr_region": v.get("psnr_region"),
                          "psnr_outside": v.get("psnr_outside")}
                         for v, t in zip(ev["per_view"], test_views)]}


def _warm_up(backend: str, camera) -> None:
    """Render once so a first-use build of the compiled rasteriser (about a minute) lands in no train_seconds."""
    import torch

    from gsgs_engine.render import render

    one = torch.zeros(1, 3)
    render(one + torch.as_tensor(camera.center, dtype=torch.float32) * 0.5, torch.tensor([[1.0, 0, 0, 0]]),
           torch.full((1, 3), 0.1), torch.ones(1), torch.zeros(1, 1, 3), camera, 0, torch.ones(3), backend=backend)


def bench_rig(scene, choice: str = "auto", log=print) -> dict:
    """The rig of the training cameras, as the effect plan reads it (gsgs train): their first frame's views
    triangulated with the known poses tell an object orbit from an inward shell, whose novel views (here the
    test cameras) are rendered with the shell's near plane (docs/inward_rigs.md)."""
    from gsgs_engine.effect_plan import rig_effect, rig_layout
    from gsgs_engine.sfm import triangulate_with_known_poses
    from gsgs_engine.train.dynamic import views_by_frame

    first = next(iter(views_by_frame(scene.train).values()))
    points = triangulate_with_known_poses(first).points if len(first) >= 2 else None
    layout = rig_effect(rig_layout([v.camera for v in first], points, scene.near, scene.far,
                                   rgb=not scene.has_alpha), choice).measured
    log(f"[bench dynamic] rig: {layout['rig']} ({layout.get('points', 0)} points of the first frame"
        + (f"; novel views drawn with a near plane of {layout['near']:.3g}" if layout.get("near") else "") + ")")
    return layout


def run_dynamic_bench(scene, out_dir: Path, iters: int, per_frame_iters: int, init: str = "random",
                      init_points: int = 2000, sh_degree: int = 0, backend: str = "auto", seed: int = 0,
                      log=print, lpips: bool = True, rig: str = "auto", techniques: str | None = None,
                      models=VARIANTS, background: str = "fixed", position_lr_scale: float = 1.0) -> dict:
    """Train and evaluate the three variants on a loaded dynamic scene (splits from the camera protocol)."""
    from gsgs_engine.bench.dynamic_region import region_masks
    from gsgs_engine import GsgsError
    from gsgs_engine.io.ply import write_gaussian_ply
    from gsgs_engine.train.dynamic import SpacetimeTrainer, views_by_frame
    from gsgs_engine.train.background_sphere import DEFAULT_WIDTH as DEFAULT_SPHERE_WIDTH
    from gsgs_engine.train.trainer import TrainConfig, Trainer

    if not scene.test:
        raise GsgsError(f"{scene.source}: no held-out views to evaluate on")
    out_dir = Path(out_dir)

    from gsgs_engine.render.project import DEFAULT_NEAR
    from gsgs_engine.train.techniques.catalogue import parse_techniques

    chosen = parse_techniques(techniques, "--techniques")  # checked before anything trains
    if background in ("mean", "sphere"):
        from dataclasses import replace

        import numpy as np

        from gsgs_engine.effect_plan import photos_mean_colour

        scene = replace(scene, background=np.asarray(photos_mean_colour(scene.train), dtype=np.float32))
        log(f"[bench dynamic] background: the training photos' mean colour {scene.background.tolist()}")
    layout = bench_rig(scene, rig, log)
    near = float(layout["near"]) if layout.get("near") else DEFAULT_NEAR

    def config(n_iters: int) -> TrainConfig:
        return TrainConfig(iters=n_iters, sh_degree=sh_degree, backend=backend, seed=seed, init=init,
                           random_init_points=init_points, checkpoint_every=0, novel_view_near=near,
                           random_background=background == "opaque", position_lr_scale=position_lr_scale,
                           background_sphere=DEFAULT_SPHERE_WIDTH if background == "sphere" else 0)

    t0 = time.perf_counter()
    _warm_up(backend, scene.test[0].camera)
    log(f"[bench dynamic] rasteriser ready ({time.perf_counter() - t0:.1f}s, not counted in train_seconds)")
    region_fn, region_what = region_masks(scene.test)
    log(f"[bench dynamic] dynamic region: {region_what}")
    results: dict = {"region": region_what, "rig": layout, "novel_view_near": near, "background": background,
                     "position_lr_scale": position_lr_scale,
                     "background_colour": [round(float(c), 4) for c in scene.background]}
    if "4d" in models:
        trainer = SpacetimeTrainer(scene, config(iters), log=log)
        results["4d"] = _train_eval(trainer, scene.test, out_dir / "renders" / "4d", log, "4d", region_fn, lpips,
                                    chosen)
        (out_dir / "4d").mkdir(parents=True, exist_ok=True)
        write_gaussian_ply(out_dir / "4d" / "point_cloud.ply", trainer.model.to_ply())
    if "static_all" in models:
        trainer = Trainer(scene, config(iters), log=log)  # the plain 3D trainer ignores camera.time
        results["static_all"] = _train_eval(trainer, scene.test, out_dir / "renders" / "static_all", log,
                                            "static_all", region_fn, lpips, chosen)
    if "static_per_frame" not in models:
        return results

    train_frames = views_by_frame(scene.train)
    test_frames = views_by_frame(scene.test)
    index = {id(v): i for i, v in enumerate(scene.views)}
    per = {"per_view": [], "train_seconds": 0.0, "iters": 0, "num_gaussians": 0, "models": 0}
    for t, test_views in test_frames.items():
        if t not in train_frames:
            raise GsgsError(f"{scene.source}: the held-out camera has a frame at t={t:.3f} that no training "
                            "camera has; the per-frame baseline needs every frame in the training cameras")
        sub = _subscene(scene, [index[id(v)] for v in train_frames[t]], [index[id(v)] for v in test_views])
        trainer = Trainer(sub, config(per_frame_iters), log=lambda msg: None)
        r = _train_eval(trainer, sub.test, out_dir / "renders" / "static_per_frame" / f"t{t:.3f}", log,
                        f"static_per_frame t={t:.3f}", region_fn, lpips, chosen)
        per["per_view"].extend(r["per_view"])
        per["train_seconds"] += r["train_seconds"]
        per["iters"] += r["iters"]
        per["num_gaussians"] += r["num_gaussians"]
        per["models"] += 1
    import numpy as np

    from gsgs_engine.train.evaluate import mean_present

    per["psnr"] = float(np.mean([v["psnr"] for v in per["per_view"]]))
    per["ssim"] = float(np.mean([v["ssim"] for v in per["per_view"]]))
    per["lpips"] = mean_present([v["lpips"] for v in per["per_view"]]) if lpips else None
    per["psnr_region"] = mean_present([v["psnr_region"] for v in per["per_view"]])
    per["psnr_outside"] = mean_present([v["psnr_outside"] for v in per["per_view"]])
    results["static_per_frame"] = per
    return results


def comparison_picture(scene, run_dir: Path, results: dict, path: Path, frames: int = 3) -> Path | None:
    """One test camera at `frames` times (first, middle, last): ground truth, the 4D model and the best static
    model (by PSNR) side by side, from the renders the bench saved; None when a render is missing."""
    import cv2
    import numpy as np

    statics = [v for v in VARIANTS if v != "4d" and v in results]
    if "4d" not in results or not statics:
        return None
    best = max(statics, key=lambda v: results[v]["psnr"])
    camera = scene.test[0].camera.extra.get("camera_index")
    views = [v for v in scene.test if v.camera.extra.get("camera_index") == camera]
    views = sorted(views, key=lambda v: v.camera.time)
    picks = [views[round(i * (len(views) - 1) / max(frames - 1, 1))] for i in range(min(frames, len(views)))]
    rows = []
    for view in picks:
        stem = view.name.replace("/", "_")
        tiles = [np.clip(view.image()[..., :3], 0, 1)]
        for model in ("4d", best):
            found = sorted((run_dir / "renders" / model).rglob(f"*_{stem}.png"))
            if not found:
                return None
            tiles.append(cv2.cvtColor(cv2.imread(str(found[0])), cv2.COLOR_BGR2RGB).astype(np.float32) / 255.0)
        rows.append(np.concatenate(tiles, axis=1))
    grid = (np.concatenate(rows, axis=0) * 255).round().astype(np.uint8)
    h, w = tiles[0].shape[:2]
    for col, label in enumerate(("ground truth", "4D", best)):
        cv2.putText(grid, label, (col * w + 6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    for row, view in enumerate(picks):
        cv2.putText(grid, f"camera {camera}, t={view.camera.time:.2f}", (6, row * h + h - 8),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), cv2.cvtColor(grid, cv2.COLOR_RGB2BGR))
    return path


def format_table(results: dict) -> str:
    def num(v, fmt: str) -> str:
        return format(v, fmt) if v is not None else "-"

    rows = [f"{'model':<18}{'PSNR':>8}{'region':>8}{'rest':>8}{'SSIM':>8}{'LPIPS':>8}{'train s':>10}{'steps':>8}"
            f"{'Gaussians':>11}"]
    for name in [v for v in VARIANTS if v in results]:
        r = results[name]
        rows.append(f"{name:<18}{r['psnr']:>8.2f}{num(r.get('psnr_region'), '.2f'):>8}"
                    f"{num(r.get('psnr_outside'), '.2f'):>8}{r['ssim']:>8.4f}"
                    f"{num(r.get('lpips'), '.4f'):>8}{r['train_seconds']:>10.1f}{r['iters']:>8d}"
                    f"{r['num_gaussians']:>11d}")
    return "\n".join(rows)


def format_markdown(every: dict) -> str:
    """One markdown table over the camera counts of a run (results.json's "cameras", or {N: results})."""
    def num(v, fmt: str) -> str:
        return format(v, fmt) if v is not None else "-"

    lines = ["| cameras | model | PSNR | dynamic region PSNR | PSNR outside it | SSIM | LPIPS (VGG) | train s "
             "| Gaussians |",
             "|---|---|---|---|---|---|---|---|---|"]
    for n in sorted(every, key=int):
        results = every[n]
        best_static = max((results[v]["psnr"] for v in VARIANTS if v != "4d" and v in results), default=None)
        for name in [v for v in VARIANTS if v in results]:
            r = results[name]
            bold = name == "4d" and best_static is not None and r["psnr"] > best_static
            psnr = f"**{r['psnr']:.2f}**" if bold else f"{r['psnr']:.2f}"
            lines.append(f"| {n} | {name} | {psnr} | {num(r.get('psnr_region'), '.2f')} | "
                         f"{num(r.get('psnr_outside'), '.2f')} | {r['ssim']:.3f} | "
                         f"{num(r.get('lpips'), '.3f')} | {r['train_seconds']:.0f} | {r['num_gaussians']} |")
    return "\n".join(lines)


def parse_camera_counts(text) -> list[int]:
    """--cameras "3,6,9" (or one count) -> [3, 6, 9]; GsgsError naming the bad value."""
    from gsgs_engine import GsgsError

    try:
        counts = [int(part) for part in str(text).split(",") if part.strip()]
    except ValueError:
        counts = []
    if not counts or any(n < 1 for n in counts):
        raise GsgsError(f"--cameras {text!r}: give one or more training camera counts, each at least 1, e.g. 3,6,9")
    return counts


def load_bench_scene(data: Path, cameras: int, frames: int, resolution_scale: float = 1.0, first_frame: int = 0):
    """The scene of one camera count: a Panoptic capture through its loader (`frames` frames from frame id
    `first_frame`), anything else through io.dynamic (camera 0 held out, `frames` frames evenly)."""
    from gsgs_engine.io.dynamic import load_dynamic_scene
    from gsgs_engine.io.loader import detect_format

    if detect_format(data) == "panoptic":
        from gsgs_engine.io import load_scene

        return load_scene(data, format="panoptic", train_views=cameras,
                          frames=f"{first_frame}-{first_frame + frames - 1}",
                          resolution_scale=resolution_scale)
    if first_frame:
        from gsgs_engine import GsgsError

        raise GsgsError(f"--first-frame {first_frame}: only a Panoptic capture takes a time window ({data} is not one)")
    return load_dynamic_scene(data, train_cameras=cameras, max_frames=frames, resolution_scale=resolution_scale)


def run(args) -> int:
    from gsgs_engine import GsgsError
    from gsgs_engine.job import write_json_atomic
    from gsgs_engine.machine import machine_record

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.threads > 0:
        import torch

        torch.set_num_threads(args.threads)
    counts = parse_camera_counts(args.cameras)
    models = [m.strip() for m in str(args.models).split(",") if m.strip()]
    if not models or any(m not in VARIANTS for m in models):
        raise GsgsError(f"--models {args.models!r}: choose from {', '.join(VARIANTS)} (comma-separated)")
    if args.iters < 1 or args.per_frame_iters < 1:
        raise GsgsError("--iters and --per-frame-iters must be at least 1")
    if args.frames < 1:
        raise GsgsError(f"--frames must be at least 1 (got {args.frames})")
    first_frame = int(getattr(args, "first_frame", 0) or 0)
    if first_frame < 0:
        raise GsgsError(f"--first-frame must be a frame id, 0 or more (got {first_frame})")
    from gsgs_engine.train.trainer import TrainConfig, validate_config

    validate_config(TrainConfig(position_lr_scale=args.position_lr_scale))  # the trainer's own rule for the rate
    rendered = None
    if args.data is not None:
        data = Path(args.data)
    else:
        data = out / "scene"
        if not _rendered_matches(data, args.ring, args.frames, args.size):
            print(f"[bench dynamic] rendering the validation scene ({args.ring} cameras x {args.frames} frames, "
                  f"{args.size} px, {args.samples} samples) into {data}", flush=True)
            t0 = time.perf_counter()
            render_scene(data, args.ring, args.frames, args.size, args.samples)
            rendered = time.perf_counter() - t0
        else:
            print(f"[bench dynamic] reusing the rendered scene in {data}", flush=True)
    log = lambda msg: print(msg, flush=True)  # noqa: E731
    every: dict = {}
    for n in counts:
        scene = load_bench_scene(data, n, args.frames, args.resolution_scale, first_frame)
        train_cams = sorted({v.camera.extra["camera_index"] for v in scene.train})
        test_cams = sorted({v.camera.extra["camera_index"] for v in scene.test})
        print(f"[bench dynamic] {n} cameras: {len(scene.train)} training views (cameras {train_cams}), "
              f"{len(scene.test)} test views (cameras {test_cams})", flush=True)
        run_dir = out if len(counts) == 1 else out / f"cameras_{n}"
        results = run_dynamic_bench(scene, run_dir, args.iters, args.per_frame_iters, args.init, args.init_points,
                                    args.sh_degree, args.backend, args.seed, log=log, lpips=not args.no_lpips,
                                    rig=args.rig, techniques=args.techniques, models=models,
                                    background=args.background, position_lr_scale=args.position_lr_scale)
        first = scene.test[0].camera
        results["setup"] = {"data": str(data), "format": scene.format, "train_cameras": train_cams,
                            "test_cameras": test_cams, "frames": len({v.camera.time for v in scene.test}),
                            "first_frame": first_frame,
                            "resolution": [first.width, first.height], "iters": args.iters,
                            "per_frame_iters": args.per_frame_iters, "init": args.init,
                            "init_points": args.init_points, "sh_degree": args.sh_degree, "backend": args.backend,
                            "techniques": args.techniques or "none", "background": args.background,
                            "seed": args.seed, "render_seconds": rendered, "threads": args.threads,
                            "machine": machine_record(),
                            "lpips": "none" if args.no_lpips else "vgg",
                            "metric": "PSNR / SSIM / LPIPS on the test cameras, averaged over every test view "
                                      "(camera x frame); region: PSNR inside " + results["region"]}
        write_json_atomic(run_dir / "results.json", results)
        picture = comparison_picture(scene, run_dir, results, run_dir / "comparison.png")
        if picture is not None:
            print(f"[bench dynamic] wrote {picture} (ground truth, 4D, best static at three times)", flush=True)
        print(f"[bench dynamic] {n} training cameras:")
        print(format_table(results))
        print(f"[bench dynamic] wrote {run_dir / 'results.json'}", flush=True)
        every[str(n)] = results
    if len(counts) > 1:
        write_json_atomic(out / "results.json", {"cameras": every})
        (out / "results.md").write_text(format_markdown(every) + "\n")
        print(format_markdown(every))
        print(f"[bench dynamic] wrote {out / 'results.json'} and results.md ({', '.join(map(str, counts))} cameras)")
    return 0


def _rendered_matches(data: Path, ring: int, frames: int, size: int) -> bool:
    """A complete render of the validation scene with these settings is in `data` (so it is reused)."""
    try:
        meta = json.loads((data / "transforms.json").read_text())
    except (OSError, ValueError):
        return False
    if meta.get("generator") != "gsgs_blender.dynamic_scene":
        return False
    if meta.get("cameras") != ring or meta.get("num_frames") != frames or meta.get("w") != size:
        return False
    return all((data / (f["file_path"] + ".png")).is_file() for f in meta.get("frames", []))


__all__ = ["add_arguments", "run", "run_dynamic_bench", "format_table", "format_markdown", "render_scene",
           "parse_camera_counts",
           "load_bench_scene"]
