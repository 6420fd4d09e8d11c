#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s45/initcache
while pgrep -f "s45/q[12].sh" > /dev/null; do sleep 10; done
export GSGS_MVS_OVERRIDE='{"max_points": 40000}'
/tmp/s45/cell.sh llff_flower llff mp40k 0-0 '{"prior": "auto"}'
/tmp/s45/cell.sh llff_horns llff mp40k 0-0 '{"prior": "auto"}'
