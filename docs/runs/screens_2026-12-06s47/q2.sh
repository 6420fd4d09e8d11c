#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s45/initcache
while pgrep -f "s47/q1.sh" >/dev/null; do sleep 5; done
O="clone_split,count_control,dropout:max_rate=0.1,binocular:every=2,opacity_decay"
for K in 1 2; do for S in blender_lego blender_chair; do
/tmp/s47/cell.sh $S blender dev4w3 $K-$K "{\"prior\": \"auto\", \"techniques\": \"$O,distortion:every=4:weight=3\"}"
done; done
for S in blender_lego blender_chair; do
/tmp/s47/cell.sh $S blender dev8w6 0-0 "{\"prior\": \"auto\", \"techniques\": \"$O,distortion:every=8:weight=6\"}"
done
