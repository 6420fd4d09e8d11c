#!/bin/bash
# seed 0 screens of the long forward recipe (clone_split not adopted): with absgrad, and with the binocular view at half size
while pgrep -f "q1[.]sh" > /dev/null; do sleep 15; done
C=/work/main/docs/runs/screens_2026-12-05s41/cell.sh
for S in llff_flower llff_horns; do
  $C $S llff L3kab 0-0 '{"prior": "auto", "iters": 3000, "techniques": ["absgrad", "count_control", "dropout:guide=density", "binocular", "opacity_decay"]}'
done
for S in llff_flower llff_horns; do
  $C $S llff L3kh 0-0 '{"prior": "auto", "iters": 3000, "techniques": ["count_control", "dropout:guide=density", "binocular:scale=0.5", "opacity_decay"]}'
done
echo "$(date +%T) q2 finished" >> /tmp/s41/queue.log
