#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s44/initcache
A='{"prior": "auto"}'
for pair in 'd192|{"num_depths": 192}' 'w5|{"window": 5}' 'w9|{"window": 9}' 'agg2|{"agg_k": 2}'; do
  tag=${pair%%|*}; ov=${pair#*|}
  for s in llff_flower llff_horns; do GSGS_MVS_OVERRIDE="$ov" ./cell.sh $s llff $tag 0-0 "$A"; done
done
