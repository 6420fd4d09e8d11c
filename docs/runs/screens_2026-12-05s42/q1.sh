#!/bin/bash
# unseen seeds 3-5 of the long forward recipe with absgrad first (seeds 0-2: 20.81 -> 21.24 dB)
C=/tmp/s42/cell.sh
for SEED in 3 4 5; do
for S in llff_flower llff_horns; do
  $C $S llff L3kab $SEED-$SEED '{"prior": "auto", "iters": 3000, "techniques": ["absgrad", "count_control", "dropout:guide=density", "binocular", "opacity_decay"]}'
done; done
echo "$(date +%T) q1 finished" >> /tmp/s42/queue.log
