#!/bin/bash
# after q2: the `fast` preset's schedule (300 steps of --prior auto) with today's recipes, seeds 0-2, all four scenes
# (session 24 measured it on an older recipe); the accuracy-against-steps plot's 300-step points
while pgrep -f "q2[.]sh" > /dev/null; do sleep 20; done
C=/tmp/s42/cell.sh
for SEED in 0 1 2; do
for S in blender_lego blender_chair; do $C $S blender auto300 $SEED-$SEED '{"prior": "auto", "iters": 300}'; done
for S in llff_flower llff_horns; do $C $S llff auto300 $SEED-$SEED '{"prior": "auto", "iters": 300}'; done
done
echo "$(date +%T) q3 finished" >> /tmp/s42/queue.log
