#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s45/initcache
while pgrep -f "s47/q3.sh" >/dev/null; do sleep 5; done
O="clone_split,count_control,dropout:max_rate=0.1,binocular:every=2,opacity_decay"
for K in 1 2; do for S in blender_lego blender_chair; do
/tmp/s47/cell.sh $S blender dev8w6 $K-$K "{\"prior\": \"auto\", \"techniques\": \"$O,distortion:every=8:weight=6\"}"
done; done
for S in blender_lego blender_chair; do
/tmp/s47/cell.sh $S blender dev16w12 0-0 "{\"prior\": \"auto\", \"techniques\": \"$O,distortion:every=16:weight=12\"}"
done
