#!/usr/bin/env python
"""How closely Blender's render of imported splats matches the engine's render (and ground truth).

    python scripts/bench_blender_fidelity.py RESULT DATA [--views 5] [--split test] [--out DIR]

RESULT: a `gsgs train --out` folder, a job's result/ folder, or a point_cloud.ply.
DATA: the dataset it was trained on (any format `gsgs train` reads).
A 4D result (a SpacetimeModel PLY, trained on a multi-view video) is compared at each picked view's
time: the engine renders the model at the view's time, and Blender plays the imported object on the
timeline (its frame range set to the capture's frame ids, the scene frame set to the view's frame, as
the add-on's frame-change handler does) and renders that frame; `--camera-index K` keeps one camera's
views, so `--views 3` compares one test camera at three frames. The seconds of each timeline update
(the viewport's per-frame cost) are recorded too.
For N views picked evenly from the split, the script
  1. renders the engine's images and writes the ground truth (composited on the background the run
     trained with), in a separate process with the engine's python (torch);
  2. imports the PLY with the add-on (gsgs_blender.splat_import: the splat material and geometry
     nodes), applies the add-on's render set-up (gsgs_blender.render_setup), creates the cameras
     and renders each view with Cycles (this process: bpy only, no torch), timing each view;
  3. scores Blender vs engine, Blender vs ground truth and engine vs ground truth (PSNR / SSIM with
     gsgs_engine.metrics, in the engine process again),
then prints a table and writes OUT/fidelity.json (and the PNGs under OUT/).
The script runs in a python that has the `bpy` module (the project's .venv has it); the engine
steps use --engine-python (default: this python).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("result", help="gsgs train --out folder, result/ folder or point_cloud.ply")
    p.add_argument("data", help="the dataset the result was trained on")
    p.add_argument("--views", type=int, default=5, help="test views to compare, picked evenly (default 5)")
    p.add_argument("--split", default="test", help="dataset split to take the views from (default test)")
    p.add_argument("--frames", default=None, help="frame ids of a multi-view video, e.g. 0-9 (default: the run's "
                                                    "recorded frames, else all)")
    p.add_argument("--resolution-scale", type=float, default=None,
                   help="image scale (default: the run's recorded one, else 1)")
    p.add_argument("--camera-index", type=int, default=None,
                   help="only the views of this camera (Camera.extra camera_index: a multi-view video's camera)")
    p.add_argument("--out", default=None, help="output folder (default RESULT_DIR/blender_fidelity)")
    p.add_argument("--engine-python", default=sys.executable,
                   help="python with torch and gsgs_engine for the engine steps (default: this one)")
    p.add_argument("--size", type=float, default=None, help="proxy half-size in sigmas (default: the add-on's)")
    p.add_argument("--bounces", type=int, default=None, help="Cycles transparent bounces (default: the add-on's)")
    p.add_argument("--samples", type=int, default=None, help="Cycles samples (default: the add-on's set-up)")
    p.add_argument("--no-dilation", action="store_true", help="turn the 0.3 px^2 dilation off (ablation)")
    p.add_argument("--no-exact-projection", action="store_true",
                   help="render the viewport's 3D cube proxies instead of camera-facing 2D Gaussians (ablation)")
    p.add_argument("--engine", choices=("CYCLES", "BLENDER_EEVEE"), default="CYCLES",
                   help="Blender render engine (default CYCLES)")
    p.add_argument("--colour", choices=("EXACT", "LINEAR"), default=None,
                   help="colour mode of the render set-up (default: the add-on's)")
    p.add_argument("--threads", type=int, default=0, help="Cycles threads (0: all cores)")
    p.add_argument("--engine-step", choices=("render", "metrics"), default=None, help=argparse.SUPPRESS)
    return p.parse_args(argv)


def find_ply(result: Path) -> Path:
    """RESULT itself when it is a file, else the shallowest point_cloud.ply under it (a job's result/ too)."""
    from gsgs_engine import GsgsError

    found = [result] if result.is_file() else sorted(result.glob("**/point_cloud.ply"), key=lambda p: len(p.parts))
    if not found:
        raise GsgsError(f"{result}: no point_cloud.ply in this folder; pass a `gsgs train --out` folder, "
                        "a job folder or a PLY")
    return found[0]


# ---------------------------------------------------------------------------------------------
# Engine steps (run in a child process with torch)
# ---------------------------------------------------------------------------------------------
def engine_render(ply: Path, data: str, split: str, count: int, out: Path, camera_index: int | None = None,
                  frames: str | None = None, resolution_scale: float | None = None) -> None:
    """Engine renders + ground truth of `count` evenly picked views; OUT/views.json lists them."""
    import numpy as np
    import torch

    from gsgs_engine import GsgsError
    from gsgs_engine.io import load_scene
    from gsgs_engine.io.ply import read_gaussian_ply
    from gsgs_engine.spacetime import SpacetimeModel, model_from_ply, render_at
    from gsgs_engine.train.evaluate import write_png
    from gsgs_engine.train.trainer import render_model

    recorded = {}
    metrics = ply.parent / "metrics.json"
    if metrics.is_file():
        recorded = json.loads(metrics.read_text()).get("plan", {})
    scale = float(resolution_scale if resolution_scale is not None else recorded.get("resolution_scale", 1.0))
    background = tuple(float(v) for v in recorded.get("background", (1.0, 1.0, 1.0)))
    scene = load_scene(data, resolution_scale=scale, background=background,
                       frames=frames if frames is not None else recorded.get("frames"))
    views = scene.split(split)
    if camera_index is not None:
        views = [v for v in views if v.camera.extra.get("camera_index") == camera_index]
        if not views:
            raise GsgsError(f"{data}: no {split} view of camera {camera_index}; its {split} cameras are "
                            f"{sorted({v.camera.extra.get('camera_index') for v in scene.split(split)}, key=str)}")
    count = max(1, min(count, len(views)))
    picks = sorted({round(i * (len(views) - 1) / max(count - 1, 1)) for i in range(count)})
    model = model_from_ply(read_gaussian_ply(ply))
    is_4d = isinstance(model, SpacetimeModel)
    if is_4d and not scene.has_time:
        raise GsgsError(f"{ply}: a 4D result, but {data} has no time; pass the multi-view video it was trained on")
    bg = torch.tensor(background, dtype=torch.float32)
    sphere = None
    if recorded.get("background_sphere"):  # the run's learned wall: the engine's final render composites it
        from gsgs_engine.train.background_sphere import BackgroundSphere

        sphere = BackgroundSphere.from_record(recorded["background_sphere"], ply.parent, scene.world_scale)
    out.mkdir(parents=True, exist_ok=True)
    listed = []
    # the run's near plane for novel views (an inward shell's; else the renderer's default): the engine's render
    # culls splats nearer than it, and the Blender camera gets it as its clip start
    from dataclasses import replace

    from gsgs_engine.render.project import DEFAULT_NEAR

    near = float(recorded.get("novel_view_near", DEFAULT_NEAR))
    for k in picks:
        view = views[k]
        camera = replace(view.camera, near=near)  # the Blender camera's clip start = the engine's near plane
        t0 = time.perf_counter()
        with torch.no_grad():
            rendered = (render_at(model, camera, bg, "auto", sh_degree=model.max_sh_degree, near=near) if is_4d
                        else render_model(model, camera, bg, "auto", near=near))
            if sphere is not None:
                rendered = sphere.composite(rendered, camera, bg)
            img = rendered.color.clamp(0.0, 1.0).cpu().numpy()
        seconds = time.perf_counter() - t0
        stem = f"view_{k:03d}"
        write_png(out / f"{stem}_engine.png", img)
        write_png(out / f"{stem}_gt.png", np.asarray(view.image(), dtype=np.float32))
        listed.append({"index": k, "name": view.name, "stem": stem, "camera": camera.to_dict(),
                       "time": view.camera.time, "frame": timeline_frame(view, scene), "engine_seconds": seconds})
    info = {"background": background, "resolution_scale": scale, "sh_degree": model.max_sh_degree,
            "num_gaussians": model.num_gaussians, "is_4d": is_4d, "views": listed,
            "background_sphere": recorded.get("background_sphere") if sphere is not None else None, "near": near,
            "world_scale": scene.world_scale}
    if is_4d:
        frames = [timeline_frame(v, scene) for v in scene.views]
        info["frame_range"] = [min(frames), max(frames)]
    (out / "views.json").write_text(json.dumps(info, indent=1))


def timeline_frame(view, scene) -> int | None:
    """The Blender frame that plays a view of a multi-view video: the capture's own frame id (its times are
    linear in the ids, io.dynamic.normalised_times), or the frame index along time when it has none."""
    if view.camera.time is None:
        return None
    if "frame" in view.camera.extra:
        return int(view.camera.extra["frame"])
    times = sorted({v.camera.time for v in scene.views})
    return times.index(view.camera.time)


def engine_metrics(out: Path) -> None:
    """PSNR / SSIM of every pair (gsgs_engine.metrics) -> OUT/pair_metrics.json."""
    import cv2
    import numpy as np
    import torch

    from gsgs_engine.metrics import psnr, ssim

    def load(path: Path) -> torch.Tensor:
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if img is None:
            raise OSError(f"{path}: cannot read the image")
        return torch.from_numpy(cv2.cvtColor(img, cv2.COLOR_BGR2RGB).astype(np.float32) / 255.0)

    listed = json.loads((out / "views.json").read_text())["views"]
    rows = []
    for v in listed:
        imgs = {k: load(out / f"{v['stem']}_{k}.png") for k in ("blender", "engine", "gt")}
        row = {"stem": v["stem"]}
        for a, b in (("blender", "engine"), ("blender", "gt"), ("engine", "gt")):
            row[f"{a}_vs_{b}"] = {"psnr": float(psnr(imgs[a], imgs[b])), "ssim": float(ssim(imgs[a], imgs[b]))}
        rows.append(row)
    (out / "pair_metrics.json").write_text(json.dumps(rows, indent=1))


def run_engine_step(python: str, step: str, args: list[str]) -> None:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    cmd = [python, str(Path(__file__).resolve()), *args, "--engine-step", step]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"engine step {step!r} failed ({' '.join(cmd)}):\n{done.stderr[-3000:]}")


# ---------------------------------------------------------------------------------------------
# Blender step (this process: bpy, no torch)
# ---------------------------------------------------------------------------------------------
def set_world_background(scene, rgb) -> None:
    """A world of the engine's background colour (given as display sRGB values), seen through every splat."""
    import bpy

    from gsgs_blender.splat_import import srgb_to_linear
    import numpy as np

    world = bpy.data.worlds.new("gsgs_fidelity_background")
    bg = world.node_tree.nodes.get("Background") or world.node_tree.nodes.new("ShaderNodeBackground")
    lin = np.asarray(rgb, dtype=np.float32)
    if scene.view_settings.view_transform != "Raw":
        lin = srgb_to_linear(lin)
    bg.inputs["Color"].default_value = (float(lin[0]), float(lin[1]), float(lin[2]), 1.0)
    bg.inputs["Strength"].default_value = 1.0
    scene.world = world


def blender_render(ply: Path, out: Path, size: float | None, bounces: int | None, samples: int | None,
                   dilation: bool, engine: str, threads: int, colour: str | None = None, exact_projection: bool = True,
                   progress=print) -> dict:
    """Import, set up and render every listed view; returns seconds and settings."""
    import bpy

    from gsgs_blender import node_groups, render_setup, splat_import, timeline
    from gsgs_blender.camera_convert import apply_camera_to_object
    from gsgs_engine.cameras import Camera

    info = json.loads((out / "views.json").read_text())
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    t0 = time.perf_counter()
    obj, import_seconds = splat_import.import_splats(ply, size=size)
    colour = colour or render_setup.DEFAULT_COLOUR_MODE
    changes = render_setup.apply(scene, colour, objects=[obj])
    if bounces is not None:
        scene.cycles.transparent_max_bounces = scene.cycles.min_transparent_bounces = int(bounces)
    if samples is not None:
        scene.cycles.samples = int(samples)
    mod = obj.modifiers[node_groups.MODIFIER_NAME]
    if not dilation:
        node_groups.set_modifier_input(mod, "Dilation", 0.0)
    node_groups.set_modifier_input(mod, "Exact Projection", bool(exact_projection))
    scene.render.engine = engine
    scene.cycles.device = "CPU"
    if threads:
        scene.render.threads_mode = "FIXED"
        scene.render.threads = threads
    scene.render.film_transparent = False
    scene.render.use_persistent_data = True
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGB"
    scene.render.image_settings.color_depth = "8"
    set_world_background(scene, info["background"])
    sphere = None
    if info.get("background_sphere"):  # the add-on's Import Result brings the learned wall: so does this check
        from gsgs_blender import background_sphere

        record = dict(info["background_sphere"])
        sphere = background_sphere.import_background_sphere(ply.parent, record, scene.collection, colour)
    cam_data = bpy.data.cameras.new("gsgs_fidelity_camera")
    cam_obj = bpy.data.objects.new("gsgs_fidelity_camera", cam_data)
    scene.collection.objects.link(cam_obj)
    scene.camera = cam_obj
    if info.get("is_4d"):
        if not timeline.playable(obj):
            raise RuntimeError(f"{ply}: the engine reads a 4D model, but the imported object does not play")
        obj[timeline.FRAME_START], obj[timeline.FRAME_END] = info["frame_range"]
    per_view = []
    updates = []
    for v in info["views"]:
        cam = Camera.from_dict(v["camera"])
        apply_camera_to_object(cam, cam_obj, scene, set_scene_frame=True)
        if sphere is not None:
            background_sphere.fit_clip_end(cam_obj, sphere)  # as the add-on's import does for the scene's cameras
        if info.get("is_4d"):
            scene.frame_set(v["frame"])
            t = time.perf_counter()
            played = timeline.update_object(obj, scene.frame_current)  # what the frame-change handler runs
            updates.append(time.perf_counter() - t)
            if abs(played - v["time"]) > 1e-6:
                raise RuntimeError(f"frame {v['frame']} plays time {played}, the view's time is {v['time']}")
        scene.render.filepath = str(out / f"{v['stem']}_blender.png")
        t = time.perf_counter()
        bpy.ops.render.render(write_still=True)
        seconds = time.perf_counter() - t
        per_view.append(seconds)
        if progress:
            progress(f"[fidelity] {v['stem']} ({cam.width}x{cam.height}) rendered in {seconds:.1f} s")
    return {"import_seconds": import_seconds, "setup_changes": changes, "render_seconds": per_view,
            "timeline_update_seconds": updates,
            "blender_total_seconds": time.perf_counter() - t0,
            "size": node_groups.get_modifier_input(mod, "Size"),
            "transparent_bounces": scene.cycles.transparent_max_bounces,
            "samples": scene.cycles.samples if engine == "CYCLES" else scene.eevee.taa_render_samples,
            "dilation": node_groups.get_modifier_input(mod, "Dilation"), "render_engine": engine,
            "colour_mode": colour, "view_transform": scene.view_settings.view_transform,
            "exact_projection": bool(exact_projection),
            "blender_version": bpy.app.version_string}


def summarise(out: Path, blender: dict) -> dict:
    info = json.loads((out / "views.json").read_text())
    pairs = json.loads((out / "pair_metrics.json").read_text())

    def mean(key, metric):
        return sum(p[key][metric] for p in pairs) / len(pairs)

    summary = {key: {"psnr": mean(key, "psnr"), "ssim": mean(key, "ssim")}
               for key in ("blender_vs_engine", "blender_vs_gt", "engine_vs_gt")}
    summary["gt_gap_db"] = summary["engine_vs_gt"]["psnr"] - summary["blender_vs_gt"]["psnr"]
    summary["seconds_per_view"] = sum(blender["render_seconds"]) / len(blender["render_seconds"])
    summary["engine_seconds_per_view"] = sum(v["engine_seconds"] for v in info["views"]) / len(info["views"])
    first = info["views"][0]["camera"]
    summary.update({"views": [v["name"] for v in info["views"]], "width": first["width"], "height": first["height"],
                    "num_gaussians": info["num_gaussians"], "sh_degree": info["sh_degree"],
                    "background": info["background"], "per_view": pairs, "blender": blender,
                    "is_4d": bool(info.get("is_4d")), "background_sphere": info.get("background_sphere"),
                    "near": info.get("near")})
    if info.get("is_4d"):
        summary["frames"] = [v["frame"] for v in info["views"]]
        summary["timeline_update_seconds_per_frame"] = (sum(blender["timeline_update_seconds"])
                                                        / len(blender["timeline_update_seconds"]))
    return summary


def table(summary: dict) -> str:
    lines = ["| comparison | PSNR (dB) | SSIM |", "|---|---|---|"]
    for key, label in (("blender_vs_engine", "Blender vs engine"), ("blender_vs_gt", "Blender vs ground truth"),
                       ("engine_vs_gt", "engine vs ground truth")):
        lines.append(f"| {label} | {summary[key]['psnr']:.2f} | {summary[key]['ssim']:.4f} |")
    b = summary["blender"]
    proxies = "camera-facing 2D Gaussians" if b["exact_projection"] else f"3D cube proxies of {b['size']:g} sigma"
    lines.append("")
    lines.append(f"{len(summary['views'])} views at {summary['width']}x{summary['height']}, "
                 f"{summary['num_gaussians']} Gaussians, SH degree {summary['sh_degree']}; "
                 f"{b['render_engine']} {b['samples']} sample(s), {b['transparent_bounces']} transparent bounces, "
                 f"{b['colour_mode'].lower()} colours ({b['view_transform']}), "
                 f"{proxies}, "
                 f"dilation {b['dilation']:g} px^2: "
                 f"{summary['seconds_per_view']:.2f} s per view (engine {summary['engine_seconds_per_view']:.2f} s); "
                 f"import {b['import_seconds']:.2f} s; "
                 f"gap to the engine vs ground truth {summary['gt_gap_db']:+.2f} dB")
    if summary.get("background_sphere"):
        lines.append(f"background: the result's learned sphere (radius {summary['background_sphere']['radius']:.3g}), "
                     f"imported as the add-on's Import Result does; near plane {summary['near']:g}")
    if summary.get("is_4d"):
        lines.append(f"4D: frames {', '.join(map(str, summary['frames']))} played on the timeline; "
                     f"{summary['timeline_update_seconds_per_frame']:.3f} s a frame to update the splats")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> dict:
    ply = find_ply(Path(args.result)).resolve()
    out = Path(args.out) if args.out else ply.parent / "blender_fidelity"
    out = out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    common = [str(ply), str(Path(args.data).resolve()), "--views", str(args.views), "--split", args.split,
              "--out", str(out)] + ([] if args.camera_index is None else ["--camera-index", str(args.camera_index)])
    common += [] if args.frames is None else ["--frames", args.frames]
    common += [] if args.resolution_scale is None else ["--resolution-scale", str(args.resolution_scale)]
    print(f"[fidelity] engine renders of {args.views} {args.split} views ...", flush=True)
    run_engine_step(args.engine_python, "render", common)
    blender = blender_render(ply, out, args.size, args.bounces, args.samples, not args.no_dilation, args.engine,
                             args.threads, args.colour, not args.no_exact_projection)
    run_engine_step(args.engine_python, "metrics", common)
    summary = summarise(out, blender)
    summary.update({"ply": str(ply), "data": str(args.data), "split": args.split})
    (out / "fidelity.json").write_text(json.dumps(summary, indent=1))
    print(table(summary))
    print(f"written {out / 'fidelity.json'}")
    return summary


def main(argv=None) -> int:
    args = parse_args(argv)
    if args.engine_step == "render":
        engine_render(Path(args.result), args.data, args.split, args.views, Path(args.out), args.camera_index,
                      args.frames, args.resolution_scale)
        return 0
    if args.engine_step == "metrics":
        engine_metrics(Path(args.out))
        return 0
    run(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
