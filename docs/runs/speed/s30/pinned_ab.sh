#!/bin/bash
# Issue 29's ratio against the pinned f6f2ab9, side by side (session 30): seed-0 auto cells, the pinned build first,
# then this build (ddd15fa's engine = c9f96c6's), one cell at a time, nothing else running. Trees exported with
# `git archive COMMIT | tar -x -C DIR` and their kernels built before.
cd /tmp
V='{"auto": {"prior": "auto"}}'
cell() { # tree tag protocol scene
  PYTHONPATH=$1 OMP_NUM_THREADS=2 /work/main/.venv/bin/python -m gsgs_engine bench sparse --protocol $3 --scene $4 --seeds 1 \
    --variants "$V" --data-root /work/shared/data --work /tmp/f6/w/$2 --doc /tmp/f6/w/$2_$4.md >> /tmp/f6/w/log_$2.txt 2>&1
  echo "$(date +%T) $2 $4 done" >> /tmp/f6/w/times.txt
}
mkdir -p /tmp/f6/w
cell /tmp/f6/tree old blender blender_lego
cell /tmp/s30/tree new blender blender_lego
cell /tmp/f6/tree old llff llff_flower
cell /tmp/s30/tree new llff llff_flower
