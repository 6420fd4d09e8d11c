#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s45/initcache
while pgrep -f "s45/q[1234568].sh" > /dev/null; do sleep 10; done
for S in llff_flower llff_horns; do
GSGS_SCREEN_WHITE_RESET=0 /tmp/s45/cell.sh $S llff whitenoreset 0-0 '{"prior": "auto"}'
GSGS_SCREEN_WHITE_RESET=1 /tmp/s45/cell.sh $S llff blackreset 0-0 '{"prior": "auto", "background": [0, 0, 0]}'
done
