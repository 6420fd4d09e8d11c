#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s45/initcache
while pgrep -f "s45/q[12345].sh" > /dev/null; do sleep 10; done
for K in 0 1 2; do
for S in blender_lego blender_chair; do
GSGS_SCREEN_ATTR_LR=1 /tmp/s45/cell.sh $S blender fastbase $K-$K '{"prior": "auto", "iters": 300}'
GSGS_SCREEN_ATTR_LR=3 /tmp/s45/cell.sh $S blender fastattr3 $K-$K '{"prior": "auto", "iters": 300}'
done; done
