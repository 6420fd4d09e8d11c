#!/bin/bash
while pgrep -f "q7.sh" > /dev/null; do sleep 10; done
export GSGS_INIT_CACHE=/tmp/s44/initcache
for k in 1 2; do for s in blender_lego blender_chair; do ./cell.sh $s blender base $k-$k '{"prior": "auto"}'; done; done
