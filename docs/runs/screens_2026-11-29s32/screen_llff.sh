#!/bin/bash
# screen: forward-facing recipe with a smaller Gaussian budget
T=/work/main
while pgrep -f screen_cc.sh > /dev/null; do sleep 5; done
for pp in ${PPS:-0.07}; do
for sc in llff_flower llff_horns; do
PYTHONPATH=$T OMP_NUM_THREADS=2 $T/.venv/bin/python -m gsgs_engine bench sparse --protocol llff --scene $sc --seeds ${SEEDS:-1} \
 --variants "{\"cc$pp\": {\"prior\": \"auto\", \"techniques\": \"absgrad,count_control:per_pixel=$pp,dropout:guide=density,binocular:scale=0.5,opacity_decay\"}}" \
 --data-root /work/shared/data --work /tmp/s32/w --doc /tmp/s32/doc_${sc}_$pp.md > /tmp/s32/log_${sc}_$pp.txt 2>&1
done; done
