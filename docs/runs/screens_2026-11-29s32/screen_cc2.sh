#!/bin/bash
# screen: orbit recipe count-control options (seed 0)
T=/work/main
while pgrep -f "screen_llff.sh|screen_cc.sh" > /dev/null; do sleep 5; done
for v in "ff025:count_control:floor_fraction=0.25" "ff04:count_control:floor_fraction=0.4"; do
name=${v%%:*}; cc=${v#*:}
for sc in blender_lego blender_chair; do
PYTHONPATH=$T OMP_NUM_THREADS=2 $T/.venv/bin/python -m gsgs_engine bench sparse --protocol blender --scene $sc --seeds ${SEEDS:-1} \
 --variants "{\"$name\": {\"prior\": \"auto\", \"techniques\": \"$cc,dropout:max_rate=0.1,binocular:every=2,opacity_decay\"}}" \
 --data-root /work/shared/data --work /tmp/s32/w --doc /tmp/s32/doc_${sc}_$name.md > /tmp/s32/log_${sc}_$name.txt 2>&1
done; done
