#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s45/initcache
while pgrep -f "s46/q6.sh" >/dev/null || pgrep -f "q6.sh" >/dev/null; do sleep 5; done
O='"clone_split,count_control,dropout:max_rate=0.1,binocular:every=2,opacity_decay'
for K in 1 2; do for S in blender_lego blender_chair; do
/tmp/s46/cell.sh $S blender odist1.0 $K-$K "{\"prior\": \"auto\", \"techniques\": $O,distortion:weight=1.0\"}"
done; done
