#!/bin/bash
# the 3-seed grid of the four protocol cells with the backward in 4 x 2 blocks
cd /tmp
for ps in "blender blender_lego" "blender blender_chair" "llff llff_flower" "llff llff_horns"; do
  set -- $ps
  echo "$(date +%T) start $2" >> /tmp/s27/grid/times.txt
  PYTHONPATH=/tmp/s27/new OMP_NUM_THREADS=2 /work/main/.venv/bin/python -m gsgs_engine bench sparse --protocol $1 --scene $2 --seeds 3 \
    --variants '{"auto": {"prior": "auto"}}' --data-root /work/shared/data --work /tmp/s27/grid/$2 --doc /tmp/s27/grid/$2.md > /tmp/s27/grid/$2.log 2>&1
  echo "$(date +%T) end $2 rc=$?" >> /tmp/s27/grid/times.txt
done
