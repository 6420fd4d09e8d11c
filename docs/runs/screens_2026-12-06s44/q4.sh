#!/bin/bash
while pgrep -f "q2.sh|q3.sh" > /dev/null; do sleep 10; done
export GSGS_INIT_CACHE=/tmp/s44/initcache
A='{"prior": "auto"}'
for pair in 'w3|{"window": 3}' 'w5d192|{"window": 5, "num_depths": 192}'; do
  tag=${pair%%|*}; ov=${pair#*|}
  for s in llff_flower llff_horns; do GSGS_MVS_OVERRIDE="$ov" ./cell.sh $s llff $tag 0-0 "$A"; done
done
