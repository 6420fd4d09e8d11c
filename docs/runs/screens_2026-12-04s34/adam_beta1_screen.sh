#!/bin/bash
# Session 34: Adam's beta1 on the orbit recipe (scratch: GSGS_ADAM_BETA1), seed 0
cd /tmp
for b in 0.95 0.8; do
 for s in blender_lego blender_chair; do
  GSGS_ADAM_BETA1=$b OMP_NUM_THREADS=2 /work/main/.venv/bin/python -m gsgs_engine bench sparse --protocol blender --scene $s --seeds 1 \
    --variants "{\"b1_$b\": {\"prior\": \"auto\"}}" --data-root /work/shared/data --work /tmp/s34/beta --doc /tmp/s34/beta_$s_$b.md >> /tmp/s34/beta_log.txt 2>&1
 done
done
echo "$(date +%T) done" >> /tmp/s34/beta_log.txt
