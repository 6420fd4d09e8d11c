#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s48/initcache
C=/tmp/s48/cell.sh
while pgrep -f q7.sh > /dev/null; do sleep 5; done
$C llff_flower llff base3k 0-0 '{"prior": "auto", "iters": 3000}'
$C llff_horns llff base3k 0-0 '{"prior": "auto", "iters": 3000}'
