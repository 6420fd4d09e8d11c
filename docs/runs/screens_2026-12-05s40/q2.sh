#!/bin/bash
while pgrep -f "q1[.]sh" > /dev/null; do sleep 20; done
C=/tmp/s40/cellenv.sh
for S in blender_lego blender_chair; do
  $C $S blender until08 1 '{"prior": "auto"}' S40_UNTIL=0.8
  $C $S blender every40 1 '{"prior": "auto"}' S40_EVERY=40
  $C $S blender every15 1 '{"prior": "auto"}' S40_EVERY=15
  $C $S blender until09 1 '{"prior": "auto"}' S40_UNTIL=0.9
done
echo "$(date +%T) q2 finished" >> /tmp/s40/queue.log
