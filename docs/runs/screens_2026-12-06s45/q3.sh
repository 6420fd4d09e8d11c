#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s45/initcache
while pgrep -f "s45/q[124].sh" > /dev/null; do sleep 10; done
export GSGS_SCREEN_ATTR_LR=3
for K in 0 1 2; do
/tmp/s45/cell.sh blender_lego blender attr3 $K-$K '{"prior": "auto"}'
/tmp/s45/cell.sh blender_chair blender attr3 $K-$K '{"prior": "auto"}'
done
