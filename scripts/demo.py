#!/usr/bin/env python
"""`make demo`: render the procedural demo scene with Blender, train without and with the prior,
compare the runs on the 25 held-out views, and save the splats with the cameras in a .blend.

    .venv/bin/python scripts/demo.py --out demo_out

demo_out/scene/      the rendered NeRF-synthetic dataset (reused when complete) + scene.blend
demo_out/<run>/      each `gsgs train` output: point_cloud.ply, metrics.json, renders/, progress.jsonl
demo_out/summary.md  the metrics table; demo_out/demo.blend: cameras + imported splats
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

T0 = time.perf_counter()


def log(message: str) -> None:
    print(f"[demo {time.perf_counter() - T0:6.1f}s] {message}", flush=True)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="demo_out", help="output folder (default demo_out)")
    p.add_argument("--resolution", type=int, default=128, help="square render size in pixels (default 128)")
    p.add_argument("--samples", type=int, default=16, help="Cycles samples per pixel (denoised; default 16)")
    p.add_argument("--iters", type=int, default=500,
                   help="training steps per run (default 500: two runs fit ~15 min on 2 CPU cores)")
    p.add_argument("--backend", default="auto", help="rasteriser backend passed to gsgs train (default auto)")
    p.add_argument("--prior", default=None,
                   help="prior for the second run (default: gsgs train's default prior, when one exists)")
    p.add_argument("--rerender", action="store_true", help="render the dataset again even if it is complete")
    p.add_argument("--skip-train", action="store_true", help="only render the dataset (and the .blend with cameras)")
    p.add_argument("--reuse-runs", action="store_true",
                   help="keep a run that already finished on the current dataset with the same prior and steps")
    p.add_argument("--threads", type=int, default=0, help="Cycles CPU threads (0 = all cores)")
    return p.parse_args(argv)


def best_run(runs: list[dict]) -> dict | None:
    """The finished run with the highest test PSNR (a run without a PSNR ranks last)."""
    ok = [r for r in runs if r.get("ok")]
    if not ok:
        return None
    return max(ok, key=lambda r: (r.get("metrics") or {}).get("psnr") or float("-inf"))


# -- (a) the dataset -----------------------------------------------------------------------------
def render_demo_dataset(scene_dir: Path, resolution: int, samples: int, threads: int, force: bool) -> None:
    import bpy  # noqa: F401  (the pip `bpy` module; fails clearly below when absent)

    from gsgs_blender.dataset_render import dataset_is_complete, render_dataset
    from gsgs_blender.demo_scene import SCENE_VERSION, TEST_VIEWS, TRAIN_VIEWS, build_demo_scene

    counts = {"train": TRAIN_VIEWS, "test": TEST_VIEWS}
    stamp_path = scene_dir / "demo_dataset.json"
    stamp = {"scene_version": SCENE_VERSION, "resolution": resolution, "samples": samples}
    try:
        same = json.loads(stamp_path.read_text()) == stamp
    except (OSError, ValueError):
        same = False
    if not force and same and dataset_is_complete(scene_dir, counts=counts):
        log(f"dataset already complete in {scene_dir} ({resolution}x{resolution}, {samples} samples, "
            f"{TRAIN_VIEWS} train + {TEST_VIEWS} test views): reusing it (--rerender to render again)")
        return
    if stamp_path.exists():
        stamp_path.unlink()  # written again only once the new renders are complete
    log(f"building the procedural scene and rendering {TRAIN_VIEWS} train + {TEST_VIEWS} test views at "
        f"{resolution}x{resolution}, Cycles CPU, {samples} samples")
    demo = build_demo_scene()
    summary = render_dataset(scene_dir, demo.splits, scene=demo.scene, resolution=resolution, samples=samples,
                             threads=threads, progress=log)
    blend = scene_dir / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), check_existing=False)
    stamp_path.write_text(json.dumps(stamp))
    log(f"rendered {TRAIN_VIEWS + TEST_VIEWS} views in {summary['seconds']:.0f} s "
        f"(denoiser: {summary['denoiser'] or 'none'}); source scene saved to {blend}")


# -- (b) training --------------------------------------------------------------------------------
def engine_env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env


def train_prior_options() -> tuple[list[str], str | None]:
    """(--prior choices, its default) as `gsgs train --help` lists them."""
    res = subprocess.run([sys.executable, "-m", "gsgs_engine", "train", "--help"], cwd=REPO, env=engine_env(),
                         capture_output=True, text=True)
    if res.returncode != 0:
        raise SystemExit(f"demo: `gsgs train --help` failed (exit {res.returncode}):\n{res.stderr.strip()}")
    return parse_prior_help(res.stdout)


def parse_prior_help(text: str) -> tuple[list[str], str | None]:
    """--prior's choices and default from `gsgs train --help`: argparse's "{a,b}" form, or prose
    such as "generative prior: none (plain 3DGS, the default), depth, warp or auto"."""
    help_text = " ".join(text.split())  # argparse wraps lines
    option = re.search(r"--prior\b(.*?)(?= --[a-z]|$)", help_text)  # this option's help, up to the next option
    segment = option.group(1) if option else ""
    d = re.search(r"\(default:?\s*([\w.-]+)\)", segment)
    default = d.group(1) if d else None
    m = re.search(r"\{([^}]*)\}", segment)
    if m:
        return [c.strip() for c in m.group(1).split(",")], default
    listed = re.search(r":(.*)", segment)
    if not listed:
        return [], default
    marked = re.search(r"([a-z][\w-]*)\s*\([^)]*\bthe default\b[^)]*\)", listed.group(1))
    if marked and default is None:
        default = marked.group(1)
    choices = []
    for item in re.split(r",|\bor\b", re.sub(r"\([^)]*\)?", "", listed.group(1))):
        word = item.strip()
        if not re.fullmatch(r"[a-z][\w-]*", word):
            break  # the list ended
        choices.append(word)
    return (choices if "none" in choices else []), default


def pick_prior(requested: str | None, options: tuple[list[str], str | None] | None = None) -> str | None:
    choices, default = options or train_prior_options()
    others = [c for c in choices if c != "none"]
    if requested is not None:
        if requested not in choices:
            raise SystemExit(f"demo: --prior {requested!r} is not offered by gsgs train (choices: {choices or ['none']})")
        return None if requested == "none" else requested
    if default and default != "none" and default in others:
        return default
    if "auto" in others:  # picks the best prior the machine has (diffusion with weights, else warping)
        return "auto"
    return others[0] if others else None


def finished_run(scene_dir: Path, run_dir: Path, prior: str, iters: int) -> dict | None:
    """metrics.json of a finished run of this prior and length, newer than the dataset; else None."""
    try:
        status = json.loads((run_dir / "status.json").read_text())
        metrics = json.loads((run_dir / "metrics.json").read_text())
        newer = (run_dir / "metrics.json").stat().st_mtime >= (scene_dir / "demo_dataset.json").stat().st_mtime
    except (OSError, ValueError):
        return None
    recorded = str((metrics.get("plan") or {}).get("prior", prior))  # "auto" runs record "auto:<generator>"
    ok = (status.get("state", status.get("status")) == "ok" and newer and metrics.get("iterations") == iters
          and recorded.split(":")[0] == prior and (run_dir / "point_cloud.ply").is_file())
    return metrics if ok else None


def train_run(scene_dir: Path, run_dir: Path, prior: str, args: argparse.Namespace) -> dict:
    if args.reuse_runs:
        metrics = finished_run(scene_dir, run_dir, prior, args.iters)
        if metrics is not None:
            log(f"reusing the finished run in {run_dir} (--reuse-runs)")
            return {"run": run_dir.name, "prior": prior, "ok": True, "wall_seconds": None,
                    "metrics": metrics, "ply": str(run_dir / "point_cloud.ply"), "reused": True}
    cmd = [sys.executable, "-m", "gsgs_engine", "train", str(scene_dir), "--out", str(run_dir),
           "--iters", str(args.iters), "--backend", args.backend, "--prior", prior]
    if run_dir.exists():
        shutil.rmtree(run_dir)  # a fresh run: the trainer would otherwise meet the last demo's checkpoints
    log("running: python " + " ".join(cmd[1:]))
    t = time.perf_counter()
    # inherit stdout/stderr: the trainer's own progress shows live
    rc = subprocess.run(cmd, cwd=REPO, env=engine_env()).returncode
    wall = time.perf_counter() - t
    if rc != 0:
        log(f"gsgs train ({prior}) failed with exit code {rc} after {wall:.0f} s; see {run_dir / 'log.txt'}")
        return {"run": run_dir.name, "prior": prior, "ok": False, "wall_seconds": wall, "exit_code": rc}
    metrics = json.loads((run_dir / "metrics.json").read_text())
    return {"run": run_dir.name, "prior": prior, "ok": True, "wall_seconds": wall, "metrics": metrics,
            "ply": str(run_dir / "point_cloud.ply")}


# -- (c) the table -------------------------------------------------------------------------------
def _fmt(value, spec: str) -> str:
    return "n/a" if value is None else format(value, spec)


def metrics_table(runs: list[dict]) -> str:
    header = "| run | prior | test PSNR | SSIM | LPIPS | Gaussians | steps | train s | wall s |"
    lines = [header, "|---" * (header.count("|") - 1) + "|"]
    for r in runs:
        m = r.get("metrics") or {}
        wall = "reused" if r.get("reused") else f"{r['wall_seconds']:.0f}{'' if r['ok'] else ' (failed)'}"
        prior = (m.get("plan") or {}).get("prior") or r["prior"]  # e.g. "auto:warp": what auto chose
        lines.append(f"| {r['run']} | {prior} | {_fmt(m.get('psnr'), '.2f')} | {_fmt(m.get('ssim'), '.4f')} | "
                     f"{_fmt(m.get('lpips'), '.4f')} | {_fmt(m.get('num_gaussians'), 'd')} | "
                     f"{_fmt(m.get('iterations'), 'd')} | {_fmt(m.get('train_seconds'), '.0f')} | "
                     f"{wall} |")
    return "\n".join(lines)


# -- (d) the .blend ------------------------------------------------------------------------------
def write_blend(out: Path, scene_dir: Path, runs: list[dict]) -> tuple[Path, str]:
    import bpy

    from gsgs_blender.demo_scene import build_demo_scene

    demo = build_demo_scene()  # same deterministic scene and camera objects the dataset was rendered with
    meta = json.loads((scene_dir / "transforms_train.json").read_text())
    demo.scene.render.resolution_x, demo.scene.render.resolution_y = meta["w"], meta["h"]
    demo.scene.render.resolution_percentage = 100
    layer = bpy.context.view_layer
    # the ground-truth geometry stays in the file for comparison, hidden so the splats show
    layer.layer_collection.children["gsgs demo objects"].hide_viewport = True
    try:
        from gsgs_blender import render_setup
        from gsgs_blender.splat_import import import_splats
    except ImportError as exc:
        note = f"cameras only: gsgs_blender.splat_import is unavailable ({exc})"
    else:
        plys = [r for r in runs if r["ok"] and Path(r["ply"]).is_file()]
        if not plys:
            note = "cameras only: no run produced a point_cloud.ply"
        else:
            coll = bpy.data.collections.new("gsgs splats")
            demo.scene.collection.children.link(coll)
            names = []
            best = best_run(plys)
            objs = []
            for r in plys:
                obj, secs = import_splats(r["ply"], collection=coll, name=f"splats_{r['run']}")
                obj.hide_set(r is not best)  # show (and render) the run with the highest test PSNR
                obj.hide_render = r is not best
                names.append(obj.name)
                objs.append(obj)
            # F12 in demo.blend then renders the splats as the engine does (docs/blender_fidelity.md)
            changes = render_setup.apply(demo.scene, objects=objs)
            note = "cameras + splats " + ", ".join(names) + f"; {len(changes)} render settings set for splats"
    path = out / "demo.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path.resolve()), check_existing=False)
    return path, note


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    out = Path(args.out).resolve()
    scene_dir = out / "scene"
    out.mkdir(parents=True, exist_ok=True)
    if not 16 <= args.resolution <= 1024:
        raise SystemExit(f"demo: --resolution {args.resolution} is out of range; use 100-128 for the demo")
    try:
        import bpy  # noqa: F401
    except ImportError:
        raise SystemExit("demo: the `bpy` module is missing from this Python; run `make demo` (it installs the "
                         "[blender] extra) or `pip install bpy` for Python 3.11") from None

    log(f"(a) dataset -> {scene_dir}")
    render_demo_dataset(scene_dir, args.resolution, args.samples, args.threads, args.rerender)

    runs: list[dict] = []
    if args.skip_train:
        log("(b) training skipped (--skip-train)")
    else:
        prior = pick_prior(args.prior)
        plan = [("baseline", "none")] + ([(f"prior_{prior}", prior)] if prior else [])
        if not prior:
            log("(b) gsgs train offers no prior yet (--prior lists only 'none'): training the baseline only")
        for name, p in plan:
            log(f"(b) training {name} (--prior {p}, {args.iters} steps)")
            runs.append(train_run(scene_dir, out / name, p, args))

        log("(c) results on the 25 held-out views")
        table = metrics_table(runs)
        print(table, flush=True)
        (out / "summary.md").write_text(f"# gsgs demo\n\n{table}\n")
        (out / "summary.json").write_text(json.dumps(
            [{k: v for k, v in r.items() if k != "metrics"} | {"metrics": {k: r.get("metrics", {}).get(k) for k in (
                "psnr", "ssim", "lpips", "num_gaussians", "iterations", "train_seconds")}} for r in runs], indent=2))
        final = best_run(runs)
        if final:
            shutil.copyfile(final["ply"], out / "point_cloud.ply")
            log(f"(d) best run's splats ({final['run']}, highest test PSNR) -> {out / 'point_cloud.ply'}")

    blend, note = write_blend(out, scene_dir, runs)
    log(f"(d) {blend}: {note}")
    total = time.perf_counter() - T0
    log(f"done in {total / 60:.1f} min" + ("" if total < 15 * 60 else " (over the 15 min target on this machine)"))
    return 0 if all(r["ok"] for r in runs) else 1


if __name__ == "__main__":
    sys.exit(main())
