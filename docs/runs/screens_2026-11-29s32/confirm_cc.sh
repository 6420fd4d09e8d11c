#!/bin/bash
T=/work/main
pp=0.035
for sc in blender_lego blender_chair; do
PYTHONPATH=$T OMP_NUM_THREADS=2 $T/.venv/bin/python -m gsgs_engine bench sparse --protocol blender --scene $sc --seeds 1-2 \
 --variants "{\"cc$pp\": {\"prior\": \"auto\", \"techniques\": \"count_control:per_pixel=$pp,dropout:max_rate=0.1,binocular:every=2,opacity_decay\"}}" \
 --data-root /work/shared/data --work /tmp/s32/w --doc /tmp/s32/doc_${sc}_${pp}_s12.md > /tmp/s32/log_${sc}_${pp}_s12.txt 2>&1
done
