#!/bin/bash
sleep 30
while pgrep -f "[.]ci/run" > /dev/null; do sleep 15; done
C=/tmp/s40/cell.sh
for S in llff_flower llff_horns; do
  $C $S llff L3k 1-1 '{"prior": "auto", "iters": 3000}'
  $C $S llff L3kcs 1-1 '{"prior": "auto", "iters": 3000, "techniques": ["clone_split", "count_control", "dropout:guide=density", "binocular", "opacity_decay"]}'
done
echo "$(date +%T) q6 finished" >> /tmp/s40/queue.log
