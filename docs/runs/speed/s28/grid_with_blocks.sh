#!/bin/bash
# (the combined build was stopped after its LLFF seeds 0-2: /tmp/s28/new = s28 branch, 8a75b14 re-applied + the compiled binocular term)
# s28 build (4x2-block backward + compiled binocular L1): LLFF seeds 0-2, orbits 0-2, then LLFF 3-4, orbits 3-5
cd /tmp
run() { # protocol scene seeds
  echo "$(date +%T) start $2 $3" >> /tmp/s28/grid/times.txt
  PYTHONPATH=/tmp/s28/new OMP_NUM_THREADS=2 /work/main/.venv/bin/python -m gsgs_engine bench sparse --protocol $1 --scene $2 --seeds $3 \
    --variants '{"auto": {"prior": "auto"}}' --data-root /work/shared/data --work /tmp/s28/grid/$2 --doc /tmp/s28/grid/$2.md >> /tmp/s28/grid/$2.log 2>&1
  echo "$(date +%T) end $2 $3 rc=$?" >> /tmp/s28/grid/times.txt
}
run llff llff_flower 3
run llff llff_horns 3
run blender blender_lego 3
run blender blender_chair 3
run llff llff_flower 3-4
run llff llff_horns 3-4
run blender blender_lego 3-5
run blender blender_chair 3-5
