#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s45/initcache
while pgrep -f "s45/q13.sh" > /dev/null; do sleep 5; done
for S in llff_flower llff_horns; do
GSGS_SCREEN_ATTR_LR=1 /tmp/s45/cell.sh $S llff fastbase 0-0 '{"prior": "auto", "iters": 300}'
GSGS_SCREEN_ATTR_LR=3 /tmp/s45/cell.sh $S llff fastattr3 0-0 '{"prior": "auto", "iters": 300}'
done
