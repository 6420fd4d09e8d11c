#!/bin/bash
# seeds 1-2 of the long forward recipe with absgrad first (seed 0: 20.87 -> 21.17 dB); the first cells beside a CI run
C=/work/main/docs/runs/screens_2026-12-05s41/cell.sh
for SEED in 1 2; do
for S in llff_flower llff_horns; do
  $C $S llff L3kab $SEED-$SEED '{"prior": "auto", "iters": 3000, "techniques": ["absgrad", "count_control", "dropout:guide=density", "binocular", "opacity_decay"]}'
done; done
echo "$(date +%T) q3 finished" >> /tmp/s41/queue.log
