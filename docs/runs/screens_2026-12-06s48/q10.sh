#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s48/initcache
C=/tmp/s48/cell.sh
for S in llff_flower llff_horns; do
$C $S llff base3k 1-1 '{"prior": "auto", "iters": 3000}'
GSGS_MVS_OVERRIDE='{"sgm_paths": 8}' $C $S llff sgm8_3k 1-1 '{"prior": "auto", "iters": 3000}' /tmp/s48/tree2
done
