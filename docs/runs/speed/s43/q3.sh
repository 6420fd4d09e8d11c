#!/bin/bash
# Issue 29's grid, equal quality: f6f2ab9's `--prior auto` (1000 steps) cell, then this build's `--prior auto` at
# N steps (N from the seed-0 step screen of q2), same scene and seed, one cell at a time, seeds 0-2.
while pgrep -f "bench sparse" > /dev/null; do sleep 5; done
cd /tmp
N=${N:-700}
cell() { # tree tag protocol scene seeds variant (f6f2ab9's --seeds is a count: the work folder's finished cells are skipped)
  PYTHONPATH=$1 OMP_NUM_THREADS=2 /work/main/.venv/bin/python -m gsgs_engine bench sparse --protocol $3 --scene $4 --seeds $5 \
    --variants "$6" --data-root /work/shared/data --work /tmp/f6/w/$2 --doc /tmp/f6/w/$2_$4_${5%%-*}.md >> /tmp/f6/w/log_$2.txt 2>&1
  echo "$(date +%T) $2 $4 seed $5 done" >> /tmp/f6/w/times.txt
}
for seed in ${SEEDS:-0 1 2}; do
  for ps in ${SCENES:-blender:blender_lego blender:blender_chair llff:llff_flower llff:llff_horns}; do
    cell /tmp/f6/tree old ${ps%%:*} ${ps#*:} $((seed + 1)) '{"auto": {"prior": "auto"}}'
    cell /tmp/s43/head new ${ps%%:*} ${ps#*:} $seed-$seed "{\"auto$N\": {\"prior\": \"auto\", \"iters\": $N}}"
  done
done
echo "$(date +%T) grid finished" >> /tmp/f6/w/times.txt
