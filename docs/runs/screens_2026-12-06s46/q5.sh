#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s45/initcache
while pgrep -f "s46/q4.sh" >/dev/null || pgrep -f "q4.sh" >/dev/null; do sleep 5; done
for K in 1 2; do for S in llff_flower llff_horns; do
/tmp/s46/cell.sh $S llff fastbase $K-$K '{"prior": "auto", "iters": 300, "attribute_lr_scale": 1}'
/tmp/s46/cell.sh $S llff fastattr3 $K-$K '{"prior": "auto", "iters": 300}'
done; done
for S in llff_flower llff_horns; do
/tmp/s46/cell.sh $S llff L3kattr3 0-0 '{"prior": "auto", "iters": 3000, "attribute_lr_scale": 3}'
/tmp/s46/cell.sh $S llff L3kbase 0-0 '{"prior": "auto", "iters": 3000}'
done
