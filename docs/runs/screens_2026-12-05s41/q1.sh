#!/bin/bash
# unseen seeds 3-5: LLFF at 3000 steps with and without clone_split first in the long forward recipe
C=/work/main/docs/runs/screens_2026-12-05s41/cell.sh
for SEED in 3 4 5; do
for S in llff_flower llff_horns; do
  $C $S llff L3k $SEED-$SEED '{"prior": "auto", "iters": 3000}'
  $C $S llff L3kcs $SEED-$SEED '{"prior": "auto", "iters": 3000, "techniques": ["clone_split", "count_control", "dropout:guide=density", "binocular", "opacity_decay"]}'
done; done
echo "$(date +%T) q1 finished" >> /tmp/s41/queue.log
