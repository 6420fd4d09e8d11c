"""Wall time of a `gsgs bench sparse` grid run one cell after another here against the same grid on a local
Ray cluster (tests/ray_local_cluster.py: N worker nodes on 127.0.0.1), and whether their numbers agree.

    python scripts/bench_cluster_grid.py --workers 2 --cpus 1 --iters 300 --out /tmp/cluster_grid

Prints a table and writes OUT/cluster_grid.json. The local grid runs first, then the cluster grid; the
cluster's start-up is timed apart. Timings on a shared machine are noisy: say what else was running.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--cpus", type=int, default=1, help="CPUs of each worker node (and of each cell)")
    parser.add_argument("--iters", type=int, default=300)
    parser.add_argument("--resolution-scale", type=float, default=0.25)
    parser.add_argument("--data-root", type=Path, default=REPO.parent / "shared" / "data")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER="0", PYTHONPATH=str(REPO))
    grid = [sys.executable, "-m", "gsgs_engine", "bench", "sparse", "--protocol", "blender", "--scene",
            "blender_lego", "--seeds", "2", "--iters", str(args.iters), "--resolution-scale",
            str(args.resolution_scale), "--data-root", str(args.data_root), "--variants",
            json.dumps({"plain": {"prior": "none"}, "auto": {"prior": "auto"}})]
    timings = {}
    t0 = time.perf_counter()
    subprocess.run(grid + ["--work", str(args.out / "local"), "--doc", str(args.out / "local.md")], env=env,
                   check=True, capture_output=True)
    timings["local (one cell after another, all cores)"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    cluster = subprocess.Popen([sys.executable, str(REPO / "tests" / "ray_local_cluster.py"), "--workers",
                                str(args.workers), "--cpus", str(args.cpus), "--temp-dir", str(args.out / "ray")],
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env)
    try:
        info = json.loads(cluster.stdout.readline())
        timings["cluster start-up (not in the grid's time)"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        subprocess.run(grid + ["--work", str(args.out / "cluster"), "--doc", str(args.out / "cluster.md"), "--ray",
                               info["address"], "--ray-cpus", str(args.cpus)], env=env, check=True, capture_output=True)
        timings[f"Ray cluster ({args.workers} workers x {args.cpus} CPU, cells side by side)"] = time.perf_counter() - t0
    finally:
        cluster.send_signal(signal.SIGTERM)
        cluster.wait(timeout=120)
    cells = {}
    for name in ("local", "cluster"):
        run = json.loads((args.out / f"{name}.json").read_text())
        cells[name] = {f"{c['variant']}/seed{c['seed']}": c["metrics"] for c in run["cells"]}
    # equal thread counts give identical numbers (tests/test_cluster.py); here the local cells use every core
    # and the cluster's one each, so float sums may round differently in the last digits
    diff = {f: max(abs(cells["local"][k][f] - cells["cluster"][k][f]) for k in cells["local"])
            for f in ("psnr", "ssim", "num_gaussians")}
    same = diff["num_gaussians"] == 0 and diff["psnr"] < 1e-4 and diff["ssim"] < 1e-6
    keys = list(timings)
    ratio = timings[keys[0]] / timings[keys[2]]
    print(f"| grid of {len(cells['local'])} cells (lego, {args.iters} steps, scale {args.resolution_scale}) | wall s |")
    print("|---|---|")
    for k, v in timings.items():
        print(f"| {k} | {v:.0f} |")
    print(f"\nlocal / cluster wall time: {ratio:.2f}x; largest difference of a cell: PSNR {diff['psnr']:.2g} dB, "
          f"SSIM {diff['ssim']:.2g}, Gaussians {diff['num_gaussians']}; {os.cpu_count()} CPU cores here")
    (args.out / "cluster_grid.json").write_text(json.dumps({"timings_s": timings, "ratio": ratio, "max_difference": diff,
                                                            "cells": cells, "cpu_count": os.cpu_count()}, indent=2))
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
