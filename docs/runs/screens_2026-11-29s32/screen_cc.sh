#!/bin/bash
# screen: orbit recipe with a smaller Gaussian budget
T=/work/main
for pp in 0.035; do
for sc in blender_lego blender_chair; do
PYTHONPATH=$T OMP_NUM_THREADS=2 $T/.venv/bin/python -m gsgs_engine bench sparse --protocol blender --scene $sc --seeds ${SEEDS:-1} \
 --variants "{\"cc$pp\": {\"prior\": \"auto\", \"techniques\": \"count_control:per_pixel=$pp,dropout:max_rate=0.1,binocular:every=2,opacity_decay\"}}" \
 --data-root /work/shared/data --work /tmp/s32/w --doc /tmp/s32/doc_${sc}_$pp.md > /tmp/s32/log_${sc}_$pp.txt 2>&1
done; done
