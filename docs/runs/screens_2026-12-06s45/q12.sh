#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s45/initcache
while pgrep -f "gsgs_engine bench sparse" > /dev/null; do sleep 5; done
for K in 1 2; do
GSGS_SCREEN_WHITE_RESET=0 /tmp/s45/cell.sh llff_flower llff whitenoreset $K-$K '{"prior": "auto"}'
GSGS_SCREEN_WHITE_RESET=0 /tmp/s45/cell.sh llff_horns llff whitenoreset $K-$K '{"prior": "auto"}'
done
for R in 1 2; do
/tmp/s45/cell.sh blender_lego blender timebase$R 0-0 '{"prior": "auto"}' /tmp/s45/tree
/tmp/s45/cell.sh blender_lego blender timehead$R 0-0 '{"prior": "auto"}' /tmp/s45/head
done
