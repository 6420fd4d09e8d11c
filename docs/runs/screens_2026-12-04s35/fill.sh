#!/bin/bash
# session 35 screen: MVS init with unmatched pixels filled (GSGS_MVS_FILL=stride), LLFF seed 0, one cell at a time
for st in $STRIDES; do for sc in llff_flower llff_horns; do
  GSGS_MVS_FILL=$st OMP_NUM_THREADS=2 /work/main/.venv/bin/python -m gsgs_engine bench sparse --protocol llff --scene $sc --seeds 1 \
    --variants '{"auto": {"prior": "auto"}}' --data-root /work/shared/data --work /tmp/s35/fill$st --doc /tmp/s35/fill$st/t.md > /tmp/s35/fill${st}_$sc.log 2>&1
  grep -h "PSNR" /tmp/s35/fill${st}_$sc.log | tail -1 | sed "s/^/fill $st $sc /" >> /tmp/s35/fill_results.txt
done; done
