#!/bin/bash
# s28b build (compiled binocular L1 only, on cf100e1): LLFF 0-2, orbits 0-2, LLFF 3-4, orbits 3-5
cd /tmp
run() { # protocol scene seeds
  echo "$(date +%T) start $2 $3" >> /tmp/s28/gridf/times.txt
  PYTHONPATH=/tmp/s28/fused OMP_NUM_THREADS=2 /work/main/.venv/bin/python -m gsgs_engine bench sparse --protocol $1 --scene $2 --seeds $3 \
    --variants '{"auto": {"prior": "auto"}}' --data-root /work/shared/data --work /tmp/s28/gridf/$2 --doc /tmp/s28/gridf/$2.md >> /tmp/s28/gridf/$2.log 2>&1
  echo "$(date +%T) end $2 $3 rc=$?" >> /tmp/s28/gridf/times.txt
}
run llff llff_flower 3
run llff llff_horns 3
run blender blender_lego 3
run blender blender_chair 3
run llff llff_flower 3-4
run llff llff_horns 3-4
run blender blender_lego 3-5
run blender blender_chair 3-5
