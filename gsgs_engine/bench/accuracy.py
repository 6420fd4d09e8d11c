"""`gsgs bench accuracy DATA --out DIR`: what accuracy costs in time, measured.

A grid of settings that trade time for accuracy (iterations, resolution scale, pseudo views,
prior rounds, maximum SH degree, prior on/off, backend). Each cell trains and evaluates in
its own process (`python -m gsgs_engine.bench.accuracy_cell`), so its peak memory is its
own (os.wait4's ru_maxrss). Results go to DIR/results.jsonl, one cell a line; a cell already
there with status "ok" is not run again. DIR/accuracy_<scene>.md is the table and
DIR/accuracy_<scene>.png the plot of PSNR against seconds with the Pareto front marked.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]

# The main trade: iterations with and without the prior. Pseudo views 8 and 2 rounds keep the
# prior's share of a short run small; full varies one factor at a time around BASE.
BASE = {"iters": 1000, "resolution_scale": 1.0, "pseudo_views": 8, "rounds": 2, "sh_degree": "auto",
        "prior": "auto", "backend": "auto"}


def grid_cells(name: str) -> list[dict]:
    """The cells of grid `name` ("small" | "full"), or of a JSON file holding a list of cell dicts."""
    from gsgs_engine import GsgsError
    from gsgs_engine.bench.accuracy_cell import normalise_cell
    from gsgs_engine.presets import PRESETS

    if name == "prior":  # the prior ablation (issue #5's table): same iterations and seed, one run
        cells = [{**BASE, "prior": "none"}, {**BASE, "prior": "depth"}, {**BASE, "prior": "warp", "depth_reg": False},
                 {**BASE, "prior": "warp"}, {**BASE, "prior": "auto"}]
    elif name == "small":
        cells = [{**BASE, "iters": it, "prior": prior} for prior in ("none", "auto") for it in (300, 1000)]
    elif name == "full":
        cells = [{**BASE, "iters": it, "prior": prior} for prior in ("none", "auto") for it in (300, 1000, 3000, 6000)]
        cells += [{**BASE, "resolution_scale": 0.5}, {**BASE, "iters": 3000, "resolution_scale": 0.5}]
        cells += [{**BASE, "pseudo_views": n} for n in (4, 16)]
        cells += [{**BASE, "rounds": r} for r in (1, 3)]
        cells += [{**BASE, "sh_degree": d} for d in (0, 3)]
        cells += [{**BASE, "prior": "depth"}]
        cells += [{**BASE, "backend": b} for b in ("reference", "cpu") + (("cuda",) if _has_cuda() else ())]
        cells += [dict(PRESETS[n]) for n in PRESETS]  # the presets' own cost, measured
    else:
        path = Path(name)
        if not path.is_file():
            raise GsgsError(f"--grid {name!r}: use small, full, prior or a JSON file with a list of cells")
        try:
            cells = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise GsgsError(f"{path}: not valid JSON ({exc}); write a list of cell objects") from None
        if not isinstance(cells, list) or not all(isinstance(c, dict) for c in cells):
            raise GsgsError(f"{path}: expected a JSON list of cell objects")
    out, seen = [], set()
    for c in cells:
        c = normalise_cell(c)
        key = cell_id(c)
        if key not in seen:  # "full" reaches BASE from several axes
            seen.add(key)
            out.append(c)
    return out


def _has_cuda() -> bool:
    try:
        import torch
    except ImportError:
        return False
    return bool(torch.cuda.is_available())


def cell_id(cell: dict) -> str:
    """A readable, unique name for a cell's settings."""
    return (f"it{cell['iters']}_rs{cell['resolution_scale']:g}"
            + (f"_ms{cell['max_side']}" if cell.get("max_side") else "")
            + f"_{cell['prior']}_pv{cell['pseudo_views']}"
            f"_r{cell['rounds']}_sh{cell['sh_degree']}_{cell['backend']}"
            + ("" if cell.get("depth_reg", True) else "_nodepth"))


# -- running ----------------------------------------------------------------------------------------
def read_results(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    records = []
    for line in path.read_text().splitlines():
        line = line.strip()
        if not line:
            continue
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:
            continue  # a line cut by a crash: that cell runs again
    return records


def run_cell_process(data: str, cell: dict, cell_dir: Path, train_views: int | None, fmt: str,
                     timeout_s: float | None = None, python: str = sys.executable) -> dict:
    """Run one cell in a child process; returns its record (status ok / error), peak memory from wait4."""
    cell_dir.mkdir(parents=True, exist_ok=True)
    (cell_dir / "cell.json").unlink(missing_ok=True)
    cmd = [python, "-m", "gsgs_engine.bench.accuracy_cell", str(data), "--out", str(cell_dir),
           "--settings", json.dumps(cell), "--format", fmt]
    if train_views is not None:
        cmd += ["--train-views", str(train_views)]
    env = _child_env()
    t0 = time.perf_counter()
    timed_out = threading.Event()
    with open(cell_dir / "log.txt", "w") as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env)

        def kill():
            timed_out.set()
            proc.kill()

        timer = threading.Timer(timeout_s, kill) if timeout_s else None
        if timer:
            timer.start()
        try:
            _, status, usage = os.wait4(proc.pid, 0)  # this child's own rusage, unlike RUSAGE_CHILDREN's max
        except BaseException:
            proc.kill()
            proc.wait()
            raise
        finally:
            if timer:
                timer.cancel()
        proc.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - t0
    record = {"id": cell_id(cell), "settings": cell, "returncode": proc.returncode, "process_seconds": round(wall, 3)}
    result_path = cell_dir / "cell.json"
    if proc.returncode == 0 and result_path.is_file():
        res = json.loads(result_path.read_text())
        peak_kb = max(usage.ru_maxrss, int(res.get("ru_maxrss_children_kb", 0)))
        record.update({"status": "ok", **{k: v for k, v in res.items() if k != "settings"},
                       "peak_memory_mb": round(peak_kb / 1024, 1)})
    else:
        tail = (cell_dir / "log.txt").read_text(errors="replace").strip().splitlines()[-3:]
        why = f"timed out after {timeout_s:g} s" if timed_out.is_set() else f"exit code {proc.returncode}"
        record.update({"status": "error", "error": why + (": " + " | ".join(tail) if tail else ""),
                       "peak_memory_mb": round(usage.ru_maxrss / 1024, 1)})
    return record


def run_cell_on_cluster(data: str, cell: dict, cell_dir: Path, train_views: int | None, fmt: str,
                        timeout_s: float | None, cluster) -> dict:
    """One cell on a Ray cluster worker (the scene folder sent along); the same record as a local cell.
    Its seconds are the worker's; process_seconds is the wall time seen here (transfers included) and
    peak memory the worker process's own."""
    from gsgs_engine import GsgsError
    from gsgs_engine.cluster.remote import RemoteCommand, folder_archive, run_remote
    from gsgs_engine.cluster.submit import echo_to, thread_env

    cell_dir.mkdir(parents=True, exist_ok=True)
    (cell_dir / "cell.json").unlink(missing_ok=True)
    argv = ["{work}/data", "--out", "{work}/out", "--settings", json.dumps(cell), "--format", fmt]
    if train_views is not None:
        argv += ["--train-views", str(train_views)]
    gpus = 1.0 if cell["backend"] == "cuda" else cluster.gpus
    command = RemoteCommand(argv=argv, inputs={"data": folder_archive(Path(data))}, out="out", local_out=cell_dir,
                            num_cpus=cluster.cpus, num_gpus=gpus, env=thread_env(cluster.cpus),
                            label=f"accuracy cell {cell_id(cell)}", module="gsgs_engine.bench.accuracy_cell")
    t0 = time.perf_counter()
    timer = threading.Timer(timeout_s, (cell_dir / "cancel.request").touch) if timeout_s else None
    with open(cell_dir / "log.txt", "w") as log:
        if timer:
            timer.start()
        try:
            code = run_remote(cluster.address, command, echo=echo_to(log), retries=cluster.retries,
                              cancel_file=cell_dir / "cancel.request")
            error = None
        except GsgsError as exc:
            code, error = 1, str(exc)
        finally:
            if timer:
                timer.cancel()
    record = {"id": cell_id(cell), "settings": cell, "returncode": code,
              "process_seconds": round(time.perf_counter() - t0, 3), "ran_on": f"Ray cluster at {cluster.address}"}
    result_path = cell_dir / "cell.json"
    if code == 0 and result_path.is_file():
        res = json.loads(result_path.read_text())
        peak_kb = max(int(res.get("ru_maxrss_self_kb", 0)), int(res.get("ru_maxrss_children_kb", 0)))
        record.update({"status": "ok", **{k: v for k, v in res.items() if k != "settings"},
                       "peak_memory_mb": round(peak_kb / 1024, 1)})
    else:
        tail = (cell_dir / "log.txt").read_text(errors="replace").strip().splitlines()[-3:]
        record.update({"status": "error", "error": error or (f"exit code {code}: " + " | ".join(tail)),
                       "peak_memory_mb": None})
    return record


def _child_env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO_ROOT), env.get("PYTHONPATH")) if p)
    return env


def prepare_cpu_backend(log=print, python: str = sys.executable) -> bool:
    """Build the compiled CPU rasteriser once before the cells, so no cell's seconds include compiling it."""
    proc = subprocess.run([python, "-m", "gsgs_engine", "build-ext"], env=_child_env(), capture_output=True, text=True)
    message = (proc.stdout + proc.stderr).strip().splitlines()
    log(message[-1] if message else f"build-ext exited with {proc.returncode}")
    return proc.returncode == 0


def run_grid(data: str, out: Path, cells: list[dict], train_views: int | None = None, fmt: str = "auto",
             timeout_s: float | None = None, name: str | None = None, log=print, cluster=None) -> list[dict]:
    """Run the cells not yet in out/results.jsonl; rewrite the table and plot after each. Returns all records.
    With `cluster` (gsgs_engine.cluster.submit.ClusterCells) the cells run side by side on a Ray cluster."""
    out.mkdir(parents=True, exist_ok=True)
    results = out / "results.jsonl"
    context = {"data": str(Path(data).resolve()), "train_views": train_views}
    done = {r["id"] for r in read_results(results)
            if r.get("status") == "ok" and {k: r.get(k) for k in context} == context}
    name = name or Path(data).resolve().name
    todo = [c for c in cells if cell_id(c) not in done]
    log(f"accuracy grid: {len(cells)} cells, {len(cells) - len(todo)} already in {results}, {len(todo)} to run")
    if cluster is None and any(c["backend"] in ("auto", "cpu") for c in todo):
        prepare_cpu_backend(log)
    if cluster is not None:
        from concurrent.futures import ThreadPoolExecutor

        from gsgs_engine.cluster.remote import connect

        connect(cluster.address)
        pool = ThreadPoolExecutor(max_workers=max(1, len(todo)))
        futures = [pool.submit(run_cell_on_cluster, data, c, out / "cells" / cell_id(c), train_views, fmt, timeout_s,
                               cluster) for c in todo]
        log(f"sent {len(todo)} cells to the Ray cluster at {cluster.address}")
    for i, cell in enumerate(todo):
        key = cell_id(cell)
        log(f"[{i + 1}/{len(todo)}] {key} ...")
        outcome = (futures[i].result() if cluster is not None
                   else run_cell_process(data, cell, out / "cells" / key, train_views, fmt, timeout_s))
        record = {**context, **outcome}
        with open(results, "a") as fh:
            fh.write(json.dumps(record) + "\n")
        if record["status"] == "ok":
            log(f"    {record['seconds']:.1f} s, PSNR {record['psnr']:.2f}, SSIM {record['ssim']:.4f}, "
                f"{record['num_gaussians']} Gaussians, {record['peak_memory_mb']:.0f} MB")
        else:
            log(f"    failed: {record['error']}")
        write_reports(out, name, log=None, with_plot=False)  # the table stays current; the plot comes at the end
    if cluster is not None:
        pool.shutdown()
    return write_reports(out, name, log=log)


# -- reporting --------------------------------------------------------------------------------------
def latest_ok(records: list[dict]) -> list[dict]:
    """The newest successful record of each cell (results.jsonl only grows)."""
    by_id: dict[str, dict] = {}
    for r in records:
        if r.get("status") == "ok" and r.get("psnr") is not None:
            by_id[r["id"]] = r
    return list(by_id.values())


def pareto_front(points: list[tuple[float, float]]) -> list[int]:
    """Indices of (seconds, psnr) points no other point beats: as fast or faster and as good or better, one strictly."""
    front = []
    for i, (s, q) in enumerate(points):
        dominated = any((s2 <= s and q2 >= q) and (s2 < s or q2 > q) for j, (s2, q2) in enumerate(points) if j != i)
        if not dominated:
            front.append(i)
    return sorted(front, key=lambda i: points[i][0])


def preset_of(cell: dict) -> str:
    from gsgs_engine.bench.accuracy_cell import normalise_cell
    from gsgs_engine.presets import PRESETS

    return next((n for n, p in PRESETS.items() if cell_id(normalise_cell(p)) == cell_id(cell)), "")


def _fmt(v, spec: str) -> str:
    return "n/a" if v is None else format(v, spec)


def prior_label(settings: dict) -> str:
    return settings["prior"] + ("" if settings.get("depth_reg", True) else " (no depth term)")


def versus_none(record: dict, rows: list[dict]) -> str:
    """"+1.23 dB, 1.9x": this cell against the prior-free cell with the same schedule ("" for that cell)."""
    s = record["settings"]
    if s["prior"] == "none":
        return ""
    same = ("iters", "resolution_scale", "sh_degree", "backend")
    base = [r for r in rows if r["settings"]["prior"] == "none" and all(r["settings"][k] == s[k] for k in same)]
    if not base:
        return "n/a"
    b = base[-1]
    return f"{record['psnr'] - b['psnr']:+.2f} dB, {record['seconds'] / max(b['seconds'], 1e-9):.1f}x"


def markdown_table(records: list[dict], title: str) -> str:
    rows = sorted(latest_ok(records), key=lambda r: r["seconds"])
    front = set(pareto_front([(r["seconds"], r["psnr"]) for r in rows]))
    lines = [f"# Accuracy against time: {title}", "",
             "seconds: training wall time of the cell (plan, SfM, training, prior, export; not the evaluation). "
             "PSNR/SSIM/LPIPS: mean over the test views at full resolution. * = on the Pareto front "
             "(no other cell is both faster and better). preset: the cell a `--preset` runs.", "",
             "vs none: PSNR difference and time ratio against the cell without a prior at the same iterations, "
             "resolution, SH and backend.", "",
             "| | preset | cell | iters | res | prior | pseudo | rounds | SH | backend | seconds | PSNR | SSIM | LPIPS "
             "| Gaussians | peak MB | vs none |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for i, r in enumerate(rows):
        s = r["settings"]
        sh = s["sh_degree"]
        if sh == "auto" and r.get("effects"):
            sh = f"auto:{r['effects']['sh_degree']['value']}"
        lines.append(f"| {'*' if i in front else ''} | {preset_of(s)} | {r['id']} | {s['iters']} | "
                     f"{s['resolution_scale']:g} | {prior_label(s)} | {s['pseudo_views']} | {s['rounds']} | {sh} | "
                     f"{s['backend']} | "
                     f"{r['seconds']:.1f} | {r['psnr']:.2f} | {_fmt(r['ssim'], '.4f')} | {_fmt(r['lpips'], '.4f')} | "
                     f"{r['num_gaussians']} | {_fmt(r.get('peak_memory_mb'), '.0f')} | {versus_none(r, rows)} |")
    ok_ids = {r["id"] for r in rows}
    failed = [r for r in records if r.get("status") != "ok" and r.get("id") not in ok_ids]  # not re-run since
    if failed:
        lines += ["", "Failed runs:", ""] + [f"- {r['id']}: {r.get('error', '')}" for r in failed]
    if rows and all(r["lpips"] is None for r in rows):
        lines += ["", f"LPIPS n/a: {rows[0].get('lpips_reason') or 'unavailable'}"]
    return "\n".join(lines) + "\n"


def plot(records: list[dict], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = sorted(latest_ok(records), key=lambda r: r["seconds"])
    pts = [(r["seconds"], r["psnr"]) for r in rows]
    front = pareto_front(pts)
    fig, ax = plt.subplots(figsize=(7.5, 4.8), dpi=110)
    colours = {"none": "tab:blue", "auto": "tab:orange", "warp": "tab:orange", "depth": "tab:green",
               "diffusion": "tab:red"}
    for r, (s, q) in zip(rows, pts):
        ax.scatter(s, q, color=colours.get(r["settings"]["prior"], "tab:gray"), s=28, zorder=3)
        label = r["id"].replace("_", " ") + (f" [{preset_of(r['settings'])}]" if preset_of(r["settings"]) else "")
        ax.annotate(label, (s, q), fontsize=6, xytext=(3, 3), textcoords="offset points")
    if front:
        ax.plot([pts[i][0] for i in front], [pts[i][1] for i in front], "-", color="black", lw=1.2,
                marker="o", mfc="none", ms=10, zorder=2, label="Pareto front")
    for prior, c in colours.items():
        if any(r["settings"]["prior"] == prior for r in rows) and prior != "warp":
            ax.scatter([], [], color=c, label=f"prior {prior}")
    ax.set_xlabel("training seconds (wall, this machine)")
    ax.set_ylabel("test PSNR (dB)")
    ax.set_title(title)
    if pts and max(p[0] for p in pts) > 4 * min(p[0] for p in pts):
        ax.set_xscale("log")
    ax.grid(True, alpha=0.3)
    ax.margins(x=0.2, y=0.1)  # room for the labels
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)


def write_reports(out: Path, name: str, log=print, with_plot: bool = True) -> list[dict]:
    records = read_results(out / "results.jsonl")
    ok = latest_ok(records)
    table = markdown_table(records, name)
    (out / f"accuracy_{name}.md").write_text(table)
    if ok and with_plot:
        plot(records, out / f"accuracy_{name}.png", f"{name}: accuracy against time")
    if log:
        log(table)
        png = f" and {out / f'accuracy_{name}.png'}" if ok and with_plot else ""
        log(f"wrote {out / f'accuracy_{name}.md'}{png}")
    return records


# -- command ----------------------------------------------------------------------------------------
def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("data", help="scene folder (e.g. ../shared/data/lego_200)")
    parser.add_argument("--out", required=True, help="output folder: results.jsonl, cells/, table and plot")
    parser.add_argument("--grid", default="small", help="small (4 cells), full (one factor at a time around "
                        "the base, about 20 cells), prior (the prior ablation: none, depth, warp without and with "
                        "the depth term, auto) or a JSON file with a list of cells")
    parser.add_argument("--train-views", type=int, default=None, help="train on N views spread over the train split")
    parser.add_argument("--format", default="auto", choices=["auto", "blender", "llff", "colmap", "job"])
    parser.add_argument("--name", default=None, help="name in the output files (default: the data folder's name)")
    parser.add_argument("--timeout", type=float, default=None, help="seconds before a cell is stopped (default none)")
    parser.add_argument("--list", action="store_true", help="print the cells and exit")
    from gsgs_engine.cluster.submit import add_ray_arguments

    add_ray_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from gsgs_engine import GsgsError

    if not Path(args.data).exists():
        raise GsgsError(f"{args.data}: no such scene folder")
    cells = grid_cells(args.grid)
    if args.list:
        for c in cells:
            print(cell_id(c))
        return 0
    cluster = None
    if getattr(args, "ray", None):
        from gsgs_engine.cluster.submit import cluster_cells

        cluster = cluster_cells(args)
    records = run_grid(args.data, Path(args.out), cells, train_views=args.train_views, fmt=args.format,
                       timeout_s=args.timeout, name=args.name, cluster=cluster)
    wanted = {cell_id(c) for c in cells}
    ok = {r["id"] for r in latest_ok(records)}
    return 0 if wanted <= ok else 1
