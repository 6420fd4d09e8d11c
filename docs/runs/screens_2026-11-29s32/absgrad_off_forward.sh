#!/bin/bash
# Session 32: the forward-facing recipe without `absgrad` on this VM (Intel Xeon, AVX-512), seeds 0-2, to pair with
# session 29's absgrad cells, which were trained on this VM too (their lego init has this VM's 16,165 MVS points),
# while their reference column was session 28's cells from the AMD VM. One cell at a time, nothing else running.
T=/work/main
for sc in llff_flower llff_horns; do
PYTHONPATH=$T OMP_NUM_THREADS=2 $T/.venv/bin/python -m gsgs_engine bench sparse --protocol llff --scene $sc --seeds ${SEEDS:-3} \
 --variants '{"noabs": {"prior": "auto", "techniques": "count_control,dropout:guide=density,binocular:scale=0.5,opacity_decay"}}' \
 --data-root /work/shared/data --work /tmp/s32/w --doc /tmp/s32/doc_${sc}_noabs.md > /tmp/s32/log_${sc}_noabs.txt 2>&1
done
