#!/bin/bash
while pgrep -f "bench sparse" > /dev/null; do sleep 5; done
C=/tmp/s43/cell.sh
$C blender_chair blender base 0-0 '{"prior": "auto"}'
GSGS_S43_SCALE=0.5 $C blender_lego blender sc05 0-0 '{"prior": "auto"}'
for S in blender_lego blender_chair; do
  $C $S blender it600 0-0 '{"prior": "auto", "iters": 600}'
  $C $S blender it750 0-0 '{"prior": "auto", "iters": 750}'
done
for S in llff_flower llff_horns; do
  $C $S llff base 0-0 '{"prior": "auto"}'
  $C $S llff it700 0-0 '{"prior": "auto", "iters": 700}'
  $C $S llff it800 0-0 '{"prior": "auto", "iters": 800}'
done
echo "$(date +%T) q2 finished" >> /tmp/s43/queue.log
