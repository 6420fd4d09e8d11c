#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s48/initcache
C=/tmp/s48/cell.sh
while pgrep -f q1.sh > /dev/null; do sleep 5; done
GSGS_MVS_OVERRIDE='{"sgm_paths": 8}' $C llff_flower llff sgm8 0-0 '{"prior": "auto"}' /tmp/s48/tree2
GSGS_MVS_OVERRIDE='{"sgm_paths": 8}' $C llff_horns llff sgm8 0-0 '{"prior": "auto"}' /tmp/s48/tree2
