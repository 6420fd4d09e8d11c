#!/bin/bash
# pinned_grid.sh's seed 2 for the NeRF-synthetic scenes only (after the session's CI run, nothing else running).
cd /tmp
V='{"auto": {"prior": "auto"}}'
cell() { # tree tag protocol scene nseeds
  PYTHONPATH=$1 OMP_NUM_THREADS=2 /work/main/.venv/bin/python -m gsgs_engine bench sparse --protocol $3 --scene $4 --seeds $5 \
    --variants "$V" --data-root /work/shared/data --work /tmp/f6/w/$2 --doc /tmp/f6/w/$2_$4.md >> /tmp/f6/w/log_$2.txt 2>&1
  echo "$(date +%T) $2 $4 seeds<$5 done" >> /tmp/f6/w/times.txt
}
for scene in blender_lego blender_chair; do
  cell /tmp/f6/tree old blender $scene 3
  cell /tmp/s31/tree new blender $scene 3
done
echo "$(date +%T) orbit seed 2 finished" >> /tmp/f6/w/times.txt
