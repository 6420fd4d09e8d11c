#!/bin/bash
while pgrep -f "q3[.]sh" > /dev/null; do sleep 10; done
C=/tmp/s40/cell.sh
for S in llff_flower llff_horns; do
  $C $S llff L3k 1 '{"prior": "auto", "iters": 3000}'
  $C $S llff L3kcs 1 '{"prior": "auto", "iters": 3000, "techniques": ["clone_split", "count_control", "dropout:guide=density", "binocular", "opacity_decay"]}'
done
echo "$(date +%T) q5 finished" >> /tmp/s40/queue.log
