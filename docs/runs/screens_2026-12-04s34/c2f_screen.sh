#!/bin/bash
# Session 34: coarse-to-fine on today's recipe, seed 0, both protocols; the recipe itself beside each (timing pair).
cd /tmp
V='{"auto": {"prior": "auto"}, "c2f50": {"prior": "auto", "coarse_fraction": 0.5, "coarse_scale": 0.5}, "c2f30": {"prior": "auto", "coarse_fraction": 0.3, "coarse_scale": 0.5}}'
for ps in blender:blender_lego llff:llff_flower blender:blender_chair llff:llff_horns; do
  OMP_NUM_THREADS=2 /work/main/.venv/bin/python -m gsgs_engine bench sparse --protocol ${ps%%:*} --scene ${ps#*:} --seeds 1 \
    --variants "$V" --data-root /work/shared/data --work /tmp/s34/c2f --doc /tmp/s34/c2f_${ps#*:}.md >> /tmp/s34/c2f_log.txt 2>&1
  echo "$(date +%T) ${ps#*:} done" >> /tmp/s34/times.txt
done
echo "$(date +%T) screen finished" >> /tmp/s34/times.txt
