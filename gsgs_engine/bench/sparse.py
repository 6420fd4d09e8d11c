"""`gsgs bench sparse`: the sparse-view protocols of the 3DGS-family papers, N seeds, mean ± std.

Protocols (../shared/METHOD.md, "Protocols"):
- llff: 3 training views of images_8 (504x378): test = every 8th image (index % 8 == 0, names
  sorted), train = round(linspace(0, n_rest - 1, 3)) over the rest (the LLFF loader's train_views=3
  does exactly this); metrics at 504x378.
- blender: NeRF-synthetic, training ids 2, 16, 26, 55, 73, 76, 86, 93 of the train split (not 75),
  test r_0 .. r_192 step 8 (25 views), 400x400 (resolution scale 0.5 of the 800 px release), white
  background; metrics at 400x400.
Metrics: PSNR, SSIM (the 3DGS Gaussian-window SSIM of gsgs_engine.metrics), LPIPS v0.1 VGG (and
AlexNet beside it), train seconds, final Gaussian count.

Each (scene, variant, seed) cell is a job folder trained by `python -m gsgs_engine run-job` in its
own process, so a variant is just job.json "settings" (the same keys `gsgs train` jobs take: "prior",
"init", "iters", "preset", technique settings the engine adds later ...). A cell whose
result/metrics.json exists and whose status is ok is not run again: re-running the command resumes.
The table (markdown) and all numbers (JSON) go to --doc (default docs/sparse_bench.{md,json}).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

from gsgs_engine.machine import machine_label, machine_record

REPO_ROOT = Path(__file__).resolve().parents[2]
BLENDER_TRAIN_IDS = ["r_2", "r_16", "r_26", "r_55", "r_73", "r_76", "r_86", "r_93"]

# protocol -> how its scenes are loaded and evaluated
PROTOCOLS: dict[str, dict] = {
    "llff": {"data": {"train_views": 3}, "settings": {"resolution_scale": 1.0},
             "scenes": ["llff_flower", "llff_horns"], "lpips_net": "vgg"},
    "blender": {"data": {"train_ids": BLENDER_TRAIN_IDS},
                "settings": {"resolution_scale": 0.5, "background": [1.0, 1.0, 1.0]},
                "scenes": ["blender_lego", "blender_chair"], "lpips_net": "vgg"},
}

# named variants: job.json "settings" each; the same dict for every scene of a protocol (nothing per scene)
VARIANTS: dict[str, dict] = {
    "3dgs (sparse SfM init)": {"prior": "none", "init": "sfm"},
    "auto": {"prior": "auto"},
}
# the ablation of issue 14 (`--variants ablation`): plain 3DGS on each initialisation, each technique alone on
# the dense initialisation (every other setting at its default), and the combination `--prior auto` runs
ABLATION: dict[str, dict] = {
    "3dgs (sparse SfM init)": VARIANTS["3dgs (sparse SfM init)"],
    "3dgs (dense init)": {"prior": "none", "init": "mvs"},
    "dense + count_control": {"prior": "none", "init": "mvs", "techniques": ["count_control"]},
    "dense + dropout": {"prior": "none", "init": "mvs", "techniques": ["dropout"]},
    "dense + binocular": {"prior": "none", "init": "mvs", "techniques": ["binocular"]},
    "dense + opacity_decay": {"prior": "none", "init": "mvs", "techniques": ["opacity_decay"]},
    "dense + warp-inpaint pseudo views": {"prior": "warp", "init": "mvs"},
    "dense + coregularisation": {"prior": "none", "init": "mvs", "techniques": ["coregularisation"]},
    "dense + exposure": {"prior": "none", "init": "mvs", "techniques": ["exposure"]},
    "dense + smoothing": {"prior": "none", "init": "mvs", "techniques": ["smoothing"]},
    "dense + absgrad": {"prior": "none", "init": "mvs", "techniques": ["absgrad"]},
    "dense + clone_split": {"prior": "none", "init": "mvs", "techniques": ["clone_split"]},
    "dense + unpool": {"prior": "none", "init": "mvs", "techniques": ["unpool"]},
    "dense + distortion": {"prior": "none", "init": "mvs", "techniques": ["distortion"]},
    "dense + depth regulariser": {"prior": "depth", "init": "mvs", "prior_settings": {"depth_source": "sparse"}},
    "auto": VARIANTS["auto"],
}
#: named variant sets `--variants NAME` selects
VARIANT_SETS: dict[str, dict[str, dict]] = {"default": VARIANTS, "ablation": ABLATION}
METRIC_KEYS = ("psnr", "ssim", "lpips_vgg", "lpips_alex", "train_seconds", "seconds", "num_gaussians")


def cell_numbers(metrics: dict) -> dict:
    """The table's numbers from a metrics.json; "seconds" = every phase but evaluation (plan, init incl.
    SfM / MVS, training loop, prior rounds), "train_seconds" = the optimisation loop alone."""
    phases = metrics.get("phase_seconds") or {}
    out = {k: metrics.get(k) for k in METRIC_KEYS if k != "seconds"}
    if phases:
        # The loop's phase clocks miss its small untimed parts (technique hooks, progress): never report
        # less than the loop's own clock plus the phases that run before it.
        before_loop = sum(phases.get(k, 0.0) for k in ("plan", "init"))
        out["seconds"] = float(max(sum(v for k, v in phases.items() if k != "evaluate"),
                                   (metrics.get("train_seconds") or 0.0) + before_loop))
    else:
        out["seconds"] = None
    return out


# the per-step profile's columns: (label, where the number comes from)
PROFILE_COLUMNS = (("proj+SH", ("kernel", "project_forward", "project_backward")),
                   ("binning", ("kernel", "binning")),
                   ("raster fwd", ("kernel", "raster_forward")),
                   ("raster bwd", ("kernel", "backward_prep", "raster_backward", "backward_reduce")),
                   ("render+loss other", ("other_render",)),
                   ("backward other", ("other_backward",)),
                   ("optimiser", ("phase", "optimise")),
                   ("densify", ("phase", "densify")))


def step_profile(metrics: dict) -> dict | None:
    """Milliseconds per training step by phase, from a cell's metrics.json (None without the kernel's clocks).

    The kernel's clocks (projection + SH, binning, compositing forward and backward) over every render of the
    loop; "render+loss other" = the trainer's render phase less the kernel's forward work (losses incl. SSIM,
    warps, dropout masks, autograd bookkeeping); "backward other" likewise for the backward; plus each
    technique's forward seconds (its extra renders and losses, kernel work included) under "technique:NAME"."""
    kernel, phases = metrics.get("kernel_seconds"), metrics.get("phase_seconds") or {}
    steps = metrics.get("iterations") or 0
    if not kernel or not steps:
        return None
    fwd = kernel.get("project_forward", 0) + kernel.get("binning", 0) + kernel.get("raster_forward", 0)
    bwd = kernel.get("backward_prep", 0) + kernel.get("raster_backward", 0) + kernel.get("backward_reduce", 0) \
        + kernel.get("project_backward", 0)
    derived = {"other_render": phases.get("render", 0) - fwd, "other_backward": phases.get("backward", 0) - bwd}
    out = {}
    for label, (source, *keys) in PROFILE_COLUMNS:
        if source == "kernel":
            value = sum(kernel.get(k, 0) for k in keys)
        elif source == "phase":
            value = sum(phases.get(k, 0) for k in keys)
        else:
            value = derived[source]
        out[label] = 1000 * value / steps
    out["step"] = 1000 * (metrics.get("train_seconds") or 0) / steps
    for name, seconds in sorted((metrics.get("technique_seconds") or {}).items()):
        out[f"technique:{name}"] = 1000 * seconds / steps
    return out


def profile_lines(records: list[dict]) -> list[str]:
    """A markdown table of `step_profile` per cell (cells run by a build without the clocks are left out)."""
    rows = [(r, r.get("profile")) for r in records if r.get("profile")]
    if not rows:
        return []
    techniques = sorted({k for _, p in rows for k in p if k.startswith("technique:")})
    labels = [label for label, _ in PROFILE_COLUMNS]
    lines = ["Where a step's time goes (ms per step, averaged over the run; kernel columns summed over every render "
             "of the step, technique columns = its forward work, kernel included; see `step_profile`):", "",
             "| scene | variant | seed | step | " + " | ".join(labels + [t.split(':', 1)[1] for t in techniques]) + " |",
             "|---|---|---|---|" + "---|" * (len(labels) + len(techniques))]
    for r, p in rows:
        lines.append(f"| {r['scene']} | {r['variant']} | {r['seed']} | {p['step']:.0f} | "
                     + " | ".join(f"{p[k]:.1f}" for k in labels) + " | "
                     + " | ".join(f"{p[t]:.1f}" if t in p else "-" for t in techniques) + (" |" if techniques else "|"))
    return lines


def cell_dir(work: Path, protocol: str, scene: str, variant: str, seed: int) -> Path:
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in variant).strip("_") or "variant"
    return work / protocol / scene / safe / f"seed{seed}"


def cell_spec(protocol: str, scene_path: Path, variant_settings: dict, seed: int, iters: int | None,
              resolution_scale: float | None) -> tuple[dict, dict]:
    """(job data, job settings) of one cell; protocol settings win over nothing, the variant over them."""
    proto = PROTOCOLS[protocol]
    data = {"path": str(scene_path.resolve()), **proto["data"]}
    settings = {**proto["settings"], **variant_settings, "seed": int(seed), "checkpoint_every": 0}
    if iters is not None:
        settings["iters"] = int(iters)
    if resolution_scale is not None:
        settings["resolution_scale"] = float(resolution_scale)
    return data, settings


def finished_metrics(folder: Path) -> dict | None:
    """metrics.json of a cell whose job ended ok, else None (to be run, or run again)."""
    from gsgs_engine.job import read_status

    metrics = folder / "result" / "metrics.json"
    status = read_status(folder) if folder.is_dir() else None
    if not metrics.is_file() or not status or status.get("state") != "ok":
        return None
    try:
        return json.loads(metrics.read_text())
    except json.JSONDecodeError:
        return None


def run_cell(folder: Path, data: dict, settings: dict, timeout_s: float | None = None,
             python: str = sys.executable, ray=None) -> tuple[dict | None, str]:
    """Write the job folder and train it in a child process (or, with `ray`, as a job on the cluster).
    Returns (metrics or None, message)."""
    from gsgs_engine.bench.accuracy import _child_env
    from gsgs_engine.job import Job

    spec = {"data": data, "settings": settings}
    if folder.is_dir() and (folder / "job.json").is_file():
        old = json.loads((folder / "job.json").read_text())
        if {k: old.get(k) for k in spec} != spec:  # settings changed: start that cell afresh
            import shutil

            shutil.rmtree(folder)
    if not (folder / "job.json").is_file():
        Job.create(folder, "train", data=data, settings=settings)
    if ray is not None:
        return _run_cell_on_cluster(folder, ray, timeout_s)
    cmd = [python, "-m", "gsgs_engine", "run-job", str(folder)]
    with open(folder / "bench_log.txt", "a") as log:
        try:
            proc = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT, env=_child_env(), timeout=timeout_s)
            code = proc.returncode
        except subprocess.TimeoutExpired:
            return None, f"timed out after {timeout_s:g} s (log: {folder / 'bench_log.txt'})"
    metrics = finished_metrics(folder)
    if metrics is None:
        tail = (folder / "bench_log.txt").read_text(errors="replace").strip().splitlines()[-3:]
        return None, f"exit code {code}: " + " | ".join(tail)
    return metrics, "ok"


def _run_cell_on_cluster(folder: Path, ray, timeout_s: float | None) -> tuple[dict | None, str]:
    from gsgs_engine import GsgsError
    from gsgs_engine.cluster.submit import echo_to, job_on_cluster

    for stale in (folder / "cancel.request", folder / "status.json"):
        stale.unlink(missing_ok=True)
    timer = None
    if timeout_s is not None:  # a cell over its time is cancelled like Ctrl-C would (checkpoint, status)
        timer = threading.Timer(timeout_s, (folder / "cancel.request").touch)
        timer.start()
    with open(folder / "bench_log.txt", "a") as log:
        try:
            code = job_on_cluster(folder, ray.address, ray.cpus, ray.gpus, ray.retries, echo=echo_to(log))
        except GsgsError as exc:
            return None, str(exc)
        finally:
            if timer is not None:
                timer.cancel()
    metrics = finished_metrics(folder)
    if metrics is None:
        tail = (folder / "bench_log.txt").read_text(errors="replace").strip().splitlines()[-3:]
        return None, f"exit code {code}: " + " | ".join(tail)
    return metrics, "ok"


def mean_std(values: list[float]) -> tuple[float | None, float | None]:
    """Mean and sample standard deviation (ddof 1; 0 for one value); None when any value is missing."""
    if not values or any(v is None or not math.isfinite(v) for v in values):
        return None, None
    mean = sum(values) / len(values)
    if len(values) == 1:
        return mean, 0.0
    return mean, math.sqrt(sum((v - mean) ** 2 for v in values) / (len(values) - 1))


def summarise(records: list[dict]) -> list[dict]:
    """Records (one per finished cell) -> rows per (protocol, scene, variant) and per (protocol, variant)
    over scenes (the mean over scenes of each seed's value, then mean ± std over seeds)."""
    rows = []
    keyed: dict[tuple, list[dict]] = {}
    for r in records:
        keyed.setdefault((r["protocol"], r["scene"], r["variant"]), []).append(r)
    for (protocol, scene, variant), cells in sorted(keyed.items()):
        row = {"protocol": protocol, "scene": scene, "variant": variant, "seeds": sorted(c["seed"] for c in cells)}
        for key in METRIC_KEYS:
            row[key] = mean_std([c["metrics"].get(key) for c in cells])
        rows.append(row)
    by_variant: dict[tuple, dict[int, list[dict]]] = {}
    for r in records:
        by_variant.setdefault((r["protocol"], r["variant"]), {}).setdefault(r["seed"], []).append(r)
    for (protocol, variant), seeds in sorted(by_variant.items()):
        scenes = {c["scene"] for cells in seeds.values() for c in cells}
        complete = {s: cells for s, cells in seeds.items() if {c["scene"] for c in cells} == scenes}
        if len(scenes) < 2 or not complete:
            continue
        row = {"protocol": protocol, "scene": "mean", "variant": variant, "seeds": sorted(complete)}
        for key in METRIC_KEYS:
            per_seed = []
            for cells in complete.values():
                vals = [c["metrics"].get(key) for c in cells]
                per_seed.append(None if any(v is None for v in vals) else sum(vals) / len(vals))
            row[key] = mean_std(per_seed)
        rows.append(row)
    return rows


def _cell(ms: tuple, spec: str, seeds: int) -> str:
    """"mean ± std" over `seeds` seeds; one seed has no spread to show: its value alone."""
    mean, std = ms
    if mean is None:
        return "n/a"
    return format(mean, spec) if seeds == 1 else f"{format(mean, spec)} ± {format(std, spec)}"


def overview(rows: list[dict], protocol: str, variants: list[str]) -> list[str]:
    """One line per variant (in the variants' order): PSNR per scene and over scenes, the change against the
    first variant, SSIM, LPIPS and total seconds over scenes. Over scenes = the protocol's mean row, or the
    only scene's row; "seeds" counts the seeds that row holds."""
    sel = {(r["scene"], r["variant"]): r for r in rows if r["protocol"] == protocol}
    scenes = [s for s in PROTOCOLS[protocol]["scenes"] if any(k[0] == s for k in sel)]
    if not scenes:
        return []

    def summary(variant: str) -> dict | None:
        return sel.get(("mean", variant)) or (sel.get((scenes[0], variant)) if len(scenes) == 1 else None)

    first = next((summary(v) for v in variants if summary(v)), None)
    lines = ["| variant | seeds | " + " | ".join(f"{s} PSNR" for s in scenes)
             + " | PSNR | vs first | SSIM | LPIPS (VGG) | total s |",
             "|---|---|" + "---|" * len(scenes) + "---|---|---|---|---|"]
    for variant in variants:
        per_scene = [sel.get((s, variant)) for s in scenes]
        if not any(per_scene):
            continue
        m = summary(variant)
        n = len(m["seeds"]) if m else 0
        gain = ("n/a" if m is None or first is None or m["psnr"][0] is None or first["psnr"][0] is None
                else f"{m['psnr'][0] - first['psnr'][0]:+.2f}")
        lines.append(f"| {variant} | {n or 'n/a'} | "
                     + " | ".join("n/a" if r is None else _cell(r["psnr"], ".2f", len(r["seeds"])) for r in per_scene)
                     + f" | {_cell(m['psnr'], '.2f', n) if m else 'n/a'} | {gain} | "
                     + (f"{_cell(m['ssim'], '.3f', n)} | {_cell(m['lpips_vgg'], '.3f', n)} | {_cell(m['seconds'], '.0f', n)} |"
                        if m else "n/a | n/a | n/a |"))
    return lines


def machines_note(labels: list[str] | None) -> list[str]:
    """What the table's cells trained on; a warning when they came from more than one machine (a cell finished on
    another machine and found in the work folder): rounding differs between processors, so do their scores."""
    if not labels:
        return []
    if len(labels) == 1:
        return [f"Cells trained on: {labels[0]}."]
    return [f"**Warning: these cells trained on {len(labels)} machines** ({'; '.join(labels)}). Another processor "
            "rounds differently and a cell's PSNR moves by up to 0.25 dB with nothing else changed "
            "(docs/sparse_techniques.md, \"One cell's PSNR under rounding alone\"): compare cells of one machine."]


def markdown(rows: list[dict], meta: dict) -> str:
    lines = [f"# Sparse-view benchmark ({meta['date']})", "",
             "Protocols: LLFF 3 views (images_8 504x378, test every 8th image, train round(linspace) over the rest); "
             "NeRF-synthetic 8 views (ids 2, 16, 26, 55, 73, 76, 86, 93; test r_0..r_192 step 8; 400x400; white "
             "background). PSNR / SSIM (3DGS Gaussian window) / LPIPS v0.1 VGG (AlexNet beside it) at those sizes; "
             "mean ± std over seeds (sample std); train s = the optimisation loop, total s = every phase but "
             "evaluation (plan, SfM / dense init, training, prior rounds).",
             f"Command: `{meta['command']}`. Machine: {meta['machine']}.", *machines_note(meta.get("cell_machines")),
             ""]
    for protocol in PROTOCOLS:
        sel = [r for r in rows if r["protocol"] == protocol]
        if not sel:
            continue
        lines += [f"## {protocol}", ""]
        if len(meta["variants"]) > 2:
            lines += ["Over scenes (each seed's mean over the scenes, then mean ± std over seeds); \"vs first\" = "
                      "PSNR against the first variant:", "", *overview(rows, protocol, list(meta["variants"])), "",
                      "Per scene:", ""]
        lines += ["| scene | variant | seeds | PSNR | SSIM | LPIPS (VGG) | LPIPS (Alex) | train s | total s | Gaussians |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for r in sel:
            n = len(r["seeds"])
            lines.append(f"| {r['scene']} | {r['variant']} | {n} | {_cell(r['psnr'], '.2f', n)} | "
                         f"{_cell(r['ssim'], '.3f', n)} | {_cell(r['lpips_vgg'], '.3f', n)} | "
                         f"{_cell(r['lpips_alex'], '.3f', n)} | {_cell(r['train_seconds'], '.0f', n)} | "
                         f"{_cell(r['seconds'], '.0f', n)} | {_cell(r['num_gaussians'], '.0f', n)} |")
        lines.append("")
    lines += ["Variants (job.json settings, the same for every scene of a protocol):", ""]
    lines += [f"- `{name}`: `{json.dumps(settings)}`" for name, settings in meta["variants"].items()]
    if meta.get("not_run"):
        lines += ["", f"Not run yet ({len(meta['not_run'])} cells; the same command without --report-only trains "
                  "them):", "", *[f"- {c}" for c in meta["not_run"]]]
    if meta.get("failures"):
        lines += ["", "Failed:", "", *[f"- {c}" for c in meta["failures"]]]
    return "\n".join(lines) + "\n"


def load_variants(spec: str | None) -> dict[str, dict]:
    """VARIANTS, a named set of VARIANT_SETS, or a JSON object {name: settings} given inline or as a file path."""
    from gsgs_engine import GsgsError

    if spec is None:
        return dict(VARIANTS)
    if spec in VARIANT_SETS:
        return dict(VARIANT_SETS[spec])
    text = Path(spec).read_text() if Path(spec).is_file() else spec
    try:
        variants = json.loads(text)
    except json.JSONDecodeError as exc:
        raise GsgsError(f"--variants: not a JSON object or a file holding one ({exc}); "
                        'e.g. \'{"plain": {"prior": "none"}}\', or a named set: '
                        + ", ".join(VARIANT_SETS)) from None
    if not isinstance(variants, dict) or not all(isinstance(v, dict) for v in variants.values()) or not variants:
        raise GsgsError("--variants: expected a JSON object mapping variant names to settings objects")
    return variants


def run_bench(protocols: list[str], scenes: list[str] | None, variants: dict[str, dict], seeds: list[int], work: Path,
        data_root: Path, doc: Path, iters: int | None = None, resolution_scale: float | None = None,
        timeout_s: float | None = None, command: str = "", log=print, train: bool = True,
        ray=None) -> list[dict]:
    """Train the cells not finished before (all of them unless `train` is False: then the table is written from
    the finished cells and the others are listed as not run) and write the table and JSON to `doc`.
    With `ray`, the cells run side by side on a Ray cluster, one job each."""
    from gsgs_engine import GsgsError
    from gsgs_engine.job import write_json_atomic

    records, failures, not_run = [], [], []
    plan = []
    for protocol in protocols:
        if protocol not in PROTOCOLS:
            raise GsgsError(f"unknown protocol {protocol!r}; use {', '.join(PROTOCOLS)}")
        for scene in PROTOCOLS[protocol]["scenes"] if scenes is None else [s for s in scenes
                                                                           if s in PROTOCOLS[protocol]["scenes"]]:
            path = data_root / scene
            if not path.is_dir():
                raise GsgsError(f"{path}: scene folder absent; pass --data-root (the folder holding {scene})")
            for variant, settings in variants.items():
                for seed in seeds:
                    plan.append((protocol, scene, path, variant, settings, seed))
    if not plan:
        raise GsgsError(f"no cells: scenes {scenes} are in none of the protocols {protocols}")
    t_start = time.perf_counter()
    cells = []  # (label, folder, job data, job settings, metrics of a finished earlier run or None)
    for protocol, scene, path, variant, settings, seed in plan:
        folder = cell_dir(work, protocol, scene, variant, seed)
        data, job_settings = cell_spec(protocol, path, settings, seed, iters, resolution_scale)
        metrics = finished_metrics(folder)
        old = json.loads((folder / "job.json").read_text()) if (folder / "job.json").is_file() else {}
        if metrics is not None and (old.get("settings") != job_settings or old.get("data") != data):
            metrics = None
        cells.append((f"{protocol}/{scene}/{variant}/seed {seed}", folder, data, job_settings, metrics))
    todo = [i for i, cell in enumerate(cells) if cell[4] is None]
    for i, (label, *_, metrics) in enumerate(cells):
        if metrics is not None:
            log(f"[{i + 1}/{len(plan)}] {label}: done before, skipped")
        elif not train:
            not_run.append(label)
    outcome: dict[int, tuple[dict | None, str]] = {}
    if train and todo and ray is not None:
        outcome = run_cells_on_cluster([cells[i] for i in todo], todo, len(plan), ray, timeout_s, log)
    elif train:
        for i in todo:
            label, folder, data, job_settings, _ = cells[i]
            log(f"[{i + 1}/{len(plan)}] {label}: training ({folder}) ...")
            outcome[i] = run_cell(folder, data, job_settings, timeout_s)
            _log_cell(outcome[i], log)
    for i, (label, folder, data, job_settings, metrics) in enumerate(cells):
        if metrics is None:
            if i not in outcome:
                continue
            metrics, message = outcome[i]
            if metrics is None:
                failures.append(f"{label}: {message}")
                continue
        protocol, scene, variant, seed = plan[i][0], plan[i][1], plan[i][3], plan[i][5]
        records.append({"protocol": protocol, "scene": scene, "variant": variant, "seed": seed,
                        "folder": str(folder), "settings": job_settings,
                        "metrics": cell_numbers(metrics), "profile": step_profile(metrics),
                        "init": metrics.get("init"), "lpips_reason": metrics.get("lpips_reason"),
                        "machine": machine_label(metrics.get("machine"))})
    rows = summarise(records)
    meta = {"date": time.strftime("%Y-%m-%d"), "command": command or "gsgs bench sparse",
            "machine": (f"{machine_label(machine_record())}, {os.cpu_count()} CPU cores" if ray is None
                        else f"Ray cluster at {ray.address} ({ray.cpus:g} CPU, {ray.gpus:g} GPU a cell)"),
            "cell_machines": sorted({r["machine"] for r in records}),
            "variants": variants,
            "seconds": round(time.perf_counter() - t_start, 1), "failures": failures, "not_run": not_run}
    doc.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(doc.with_suffix(".json"), {"meta": meta, "rows": rows, "cells": records})
    profile = profile_lines(records)
    doc.with_suffix(".md").write_text(markdown(rows, meta) + ("\n" + "\n".join(profile) + "\n" if profile else ""))
    log(f"wrote {doc.with_suffix('.md')} and {doc.with_suffix('.json')} ({len(records)} cells, "
        f"{len(failures)} failed" + (f", {len(not_run)} not run" if not_run else "") + ")")
    return rows


def _log_cell(result: tuple[dict | None, str], log) -> None:
    metrics, message = result
    if metrics is None:
        log(f"    failed: {message}")
    else:
        log(f"    PSNR {metrics['psnr']:.2f}, SSIM {metrics['ssim']:.3f}, LPIPS(VGG) {metrics.get('lpips_vgg')}, "
            f"{metrics['train_seconds']:.0f} s, {metrics['num_gaussians']} Gaussians")


def run_cells_on_cluster(cells: list[tuple], indices: list[int], total: int, ray,
                         timeout_s: float | None, log) -> dict[int, tuple[dict | None, str]]:
    """Every cell as a job on the cluster, all submitted at once (Ray queues what the workers cannot take
    yet); each cell's job folder fills here as on a local run. Ctrl-C cancels them all."""
    from concurrent.futures import ThreadPoolExecutor

    from gsgs_engine.cluster.remote import connect

    connect(ray.address)  # the address check and the connection happen once, before any cell is sent

    def one(position: int) -> tuple[dict | None, str]:
        label, folder, data, settings, _ = cells[position]
        log(f"[{indices[position] + 1}/{total}] {label}: sent to the cluster ({folder}) ...")
        result = run_cell(folder, data, settings, timeout_s, ray=ray)
        log(f"[{indices[position] + 1}/{total}] {label}: finished")
        _log_cell(result, log)
        return result

    with ThreadPoolExecutor(max_workers=max(1, len(cells))) as pool:
        futures = [pool.submit(one, k) for k in range(len(cells))]
        try:
            results = [f.result() for f in futures]
        except KeyboardInterrupt:  # each cell's driver thread sees its cancel request and stops its run
            for _, folder, *_ in cells:
                (folder / "cancel.request").touch()
            raise
    return {indices[k]: results[k] for k in range(len(cells))}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--protocol", action="append", choices=sorted(PROTOCOLS), default=None,
                        help="llff and/or blender (default both)")
    parser.add_argument("--scene", action="append", default=None, help="only these scenes (e.g. llff_flower)")
    parser.add_argument("--variants", default=None,
                        help="a named set (" + ", ".join(f"{k}: {len(v)} variants" for k, v in VARIANT_SETS.items())
                        + '; default: default), or JSON {name: settings}, or a file holding it')
    parser.add_argument("--seeds", type=parse_seeds, default=[0, 1, 2],
                        help="N (seeds 0 .. N-1; default 3), a range A-B (seeds A .. B) or a list 1,2: a grid "
                             "can be split over machines or sessions and resumed")
    parser.add_argument("--iters", type=int, default=None, help="override every variant's iterations")
    parser.add_argument("--resolution-scale", type=float, default=None,
                        help="override the protocol's resolution (smoke tests only: the numbers stop being comparable)")
    parser.add_argument("--data-root", type=Path, default=REPO_ROOT.parent / "shared" / "data")
    parser.add_argument("--work", type=Path, default=Path("bench_sparse"), help="cell folders (resumable)")
    parser.add_argument("--doc", type=Path, default=REPO_ROOT / "docs" / "sparse_bench.md",
                        help="the markdown table; the JSON goes beside it")
    parser.add_argument("--timeout", type=float, default=None, help="seconds per cell")
    from gsgs_engine.cluster.submit import add_ray_arguments

    add_ray_arguments(parser)
    parser.add_argument("--report-only", action="store_true",
                        help="train nothing: write the table from the cells finished before and list the others")


def parse_seeds(text: str) -> list[int]:
    """--seeds: "N" -> 0 .. N-1, "A-B" -> A .. B, "a,b,c" -> those; seeds are >= 0, at least one."""
    text = str(text).strip()
    try:
        if "," in text:
            seeds = [int(part) for part in text.split(",") if part.strip()]
        elif "-" in text.lstrip("-"):
            lo, hi = (int(part) for part in text.split("-", 1))
            seeds = list(range(lo, hi + 1))
        else:
            count = int(text)
            if count < 1:
                raise argparse.ArgumentTypeError(f"--seeds {text}: at least one seed (N >= 1)")
            seeds = list(range(count))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--seeds {text!r}: write N (seeds 0 .. N-1), A-B or a list 1,2") from None
    if not seeds or min(seeds) < 0:
        raise argparse.ArgumentTypeError(f"--seeds {text!r}: seeds are integers >= 0, at least one")
    return sorted(set(seeds))


def _own_arguments(argv: list[str]) -> list[str]:
    """The arguments after `bench sparse` (`gsgs bench sparse ...` passes the whole command line)."""
    argv = list(argv)
    for i in range(len(argv) - 1):
        if argv[i] == "bench" and argv[i + 1] == "sparse":
            return argv[i + 2:]
    return argv


def run(args: argparse.Namespace) -> int:
    """`gsgs bench sparse ...` (gsgs_engine.cli raises GsgsError as one `gsgs: error:` line)."""
    cluster = None
    if getattr(args, "ray", None):
        from gsgs_engine.cluster.submit import cluster_cells

        cluster = cluster_cells(args)
    run_bench(args.protocol or list(PROTOCOLS), args.scene, load_variants(args.variants), list(args.seeds),
              args.work, args.data_root, args.doc, args.iters, args.resolution_scale, args.timeout,
              command="gsgs bench sparse " + " ".join(_own_arguments(getattr(args, "_argv", None) or sys.argv[1:])),
              train=not getattr(args, "report_only", False), ray=cluster)
    return 0


def main(argv: list[str] | None = None) -> int:
    """`python -m gsgs_engine.bench.sparse ...` (the same as `gsgs bench sparse ...`)."""
    from gsgs_engine import GsgsError

    parser = argparse.ArgumentParser(prog="gsgs bench sparse", description=__doc__.split("\n")[0])
    add_arguments(parser)
    args = parser.parse_args(argv)
    args._argv = argv if argv is not None else sys.argv[1:]
    try:
        return run(args)
    except GsgsError as exc:
        print(f"gsgs: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
