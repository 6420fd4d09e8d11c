#!/bin/bash
while pgrep -f "q[123][.]sh" > /dev/null; do sleep 20; done
C=/tmp/s40/cell.sh
for seed in 3 4 5; do for S in llff_flower llff_horns; do
  $C $S llff planned $seed-$seed '{"prior": "auto"}'
  $C $S llff nodrop $seed-$seed '{"prior": "auto", "techniques": ["absgrad", "count_control", "binocular:scale=0.5", "opacity_decay"]}'
done; done
echo "$(date +%T) q4 finished" >> /tmp/s40/queue.log
