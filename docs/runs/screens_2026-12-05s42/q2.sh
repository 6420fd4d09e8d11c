#!/bin/bash
# after q1: the orbit recipe with the binocular view from 0.3 of the run (seed 0: 27.01 -> 27.04, session 39), seeds 1-2;
# then the long forward recipe with absgrad and the half-size binocular view (L3kabh), seed 0
while pgrep -f "q1[.]sh" > /dev/null; do sleep 20; done
C=/tmp/s42/cell.sh
for SEED in 1 2; do
for S in blender_lego blender_chair; do
  $C $S blender bin03 $SEED-$SEED '{"prior": "auto", "techniques": ["clone_split", "count_control", "dropout:max_rate=0.1", "binocular:every=2:start_fraction=0.3", "opacity_decay"]}'
done; done
for S in llff_flower llff_horns; do
  $C $S llff L3kabh 0-0 '{"prior": "auto", "iters": 3000, "techniques": ["absgrad", "count_control", "dropout:guide=density", "binocular:scale=0.5", "opacity_decay"]}'
done
echo "$(date +%T) q2 finished" >> /tmp/s42/queue.log
