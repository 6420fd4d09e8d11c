#!/bin/bash
while pgrep -f "q[12][.]sh" > /dev/null; do sleep 20; done
C=/tmp/s40/cell.sh
for S in llff_flower llff_horns; do
  $C $S llff nodrop 1-2 '{"prior": "auto", "techniques": ["absgrad", "count_control", "binocular:scale=0.5", "opacity_decay"]}'
  $C $S llff planned 1-2 '{"prior": "auto"}'
done
echo "$(date +%T) q3 finished" >> /tmp/s40/queue.log
