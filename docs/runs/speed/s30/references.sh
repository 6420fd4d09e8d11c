#!/bin/bash
# The Train panel's time-estimate references measured again with this build (session 30): the machine probe, the
# three reference cells one after another (seed 0, 1000 steps, two threads, nothing else running), the probe again.
# Run from outside the checkout: bash docs/runs/speed/s30/references.sh OUTDIR
set -e
OUT=${1:-/tmp/refs30}
PY=/work/main/.venv/bin/python
mkdir -p "$OUT"
cd /tmp
probe() { OMP_NUM_THREADS=2 PYTHONPATH=/work/main $PY -m gsgs_engine bench machine --threads 2 2>/dev/null | grep "^{" >> "$OUT/probes.txt"; }
probe; probe; probe
run() {  # protocol scene variants
  OMP_NUM_THREADS=2 PYTHONPATH=/work/main $PY -m gsgs_engine bench sparse --protocol "$1" --scene "$2" --seeds 1 \
    --variants "$3" --data-root /work/shared/data --work "$OUT/cells" --doc "$OUT/$2.md" >> "$OUT/log.txt" 2>&1
}
run llff llff_flower '{"plain": {"prior": "none"}}'
run blender blender_lego '{"auto": {"prior": "auto"}}'
run llff llff_flower '{"auto": {"prior": "auto"}}'
probe; probe; probe
