#!/bin/bash
# The Train panel's time estimate for the two recipes it had no reference for (session 37), two threads, one run at a
# time, nothing else running, the machine probe before and after. Run from outside the checkout:
#   bash docs/runs/speed/s37/estimate_runs.sh references OUTDIR
#     the still inward shell (Panoptic frame 0, 9 cameras, 640x360, `--prior auto`: the binocular view every step and
#     the background sphere) and the 4D recipe (the same 9 cameras, frames 0-9 at 320x180), each right after the orbit
#     reference cell (lego auto, seed 0, 1000 steps); the references are the orbit's 97.7 s x (run / that lego cell)
#   bash docs/runs/speed/s37/estimate_runs.sh check OUTDIR
#     the check they were not fitted to: the same two recipes with 3 of the cameras, against the references x probe
set -e
MODE=$1
OUT=${2:-/tmp/estimate37_$MODE}
PY=/work/main/.venv/bin/python
DATA=/work/shared/data
mkdir -p "$OUT"
cd /tmp
export OMP_NUM_THREADS=2 PYTHONPATH=/work/main
probe() { $PY -m gsgs_engine bench machine --threads 2 2>/dev/null | grep "^{" >> "$OUT/probes.txt"; }
pano() {  # name cameras frames scale
  $PY -m gsgs_engine train $DATA/panoptic_basketball --train-views "$2" --frames "$3" --resolution-scale "$4" \
    --prior auto --iters 1000 --seed 0 --out "$OUT/$1" >> "$OUT/log.txt" 2>&1
}
probe; probe; probe
if [ "$MODE" = references ]; then
  $PY -m gsgs_engine bench sparse --protocol blender --scene blender_lego --seeds 1 --variants '{"auto": {"prior": "auto"}}' \
    --data-root $DATA --work "$OUT/cells" --doc "$OUT/lego.md" >> "$OUT/log.txt" 2>&1
  pano shell_f0_c9 9 0 1.0
  pano video_c9 9 0-9 0.5
else
  pano shell_f0_c3 3 0 1.0
  pano video_c3 3 0-9 0.5
fi
probe; probe; probe
$PY - "$MODE" "$OUT" <<'PYEOF'
import json, statistics, sys
from pathlib import Path
sys.path.insert(0, "/work/main")
from gsgs_blender import train_estimate as te
mode, out = sys.argv[1], Path(sys.argv[2])
probes = [json.loads(l)["probe_ms"] for l in (out / "probes.txt").read_text().splitlines()]
factor = statistics.median(probes) / te.PROBE_REFERENCE_MS
print(f"probes (ms): {probes}, median {statistics.median(probes):.1f}, factor {factor:.3f}")
metrics = lambda p: json.loads(p.read_text())
if mode == "references":
    lego = metrics(next((out / "cells").rglob("metrics.json")))["train_seconds"]
    for name in ("shell_f0_c9", "video_c9"):
        m = metrics(out / name / "metrics.json")
        print(f"{name}: train {m['train_seconds']:.1f} s, {m['num_gaussians']} Gaussians, PSNR {m['psnr']:.2f}, "
              f"x lego ({lego:.1f} s) {m['train_seconds'] / lego:.3f} -> reference {97.7 * m['train_seconds'] / lego:.1f} s")
else:
    for name, kind, scale in (("shell_f0_c3", "inward", 1.0), ("video_c3", "video", 0.5)):
        m = metrics(out / name / "metrics.json")
        ref, px = te.REFERENCES[kind]
        est = ref * (max(640 * 360 * scale * scale / px, te.MIN_PIXEL_FACTOR)) ** te.PIXEL_EXPONENT * factor
        print(f"{name}: train {m['train_seconds']:.1f} s, {m['num_gaussians']} Gaussians, PSNR {m['psnr']:.2f}; "
              f"estimate (references x probe) {est:.1f} s, taken / stated {m['train_seconds'] / est:.2f}")
PYEOF
