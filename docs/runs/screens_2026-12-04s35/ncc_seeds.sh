#!/bin/bash
# session 35: NCC >= 0.7 in the plane sweep (scratch override, mvs_override_scratch.diff), LLFF seeds 1-2, one cell at a time
# (the recipe's cells of these seeds: session 33's grid, docs/runs/speed/s33/cells/new_*)
cd /tmp
for seed in 1 2; do for sc in llff_flower llff_horns; do
  GSGS_MVS_OVERRIDE='{"min_ncc": 0.7}' PYTHONPATH=/tmp/s35/tree4 OMP_NUM_THREADS=2 /work/main/.venv/bin/python -m gsgs_engine bench sparse --protocol llff --scene $sc --seeds $seed-$seed \
    --variants '{"auto": {"prior": "auto"}}' --data-root /work/shared/data --work /tmp/s35/nccs --doc /tmp/s35/nccs/t.md > /tmp/s35/nccs_${sc}_$seed.log 2>&1
  grep -h "PSNR" /tmp/s35/nccs_${sc}_$seed.log | tail -1 | sed "s/^/ncc07 $sc seed $seed /" >> /tmp/s35/nccs_results.txt
done; done
