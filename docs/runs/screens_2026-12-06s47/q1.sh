#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s45/initcache
O="clone_split,count_control,dropout:max_rate=0.1,binocular:every=2,opacity_decay"
for S in blender_lego blender_chair; do
/tmp/s47/cell.sh $S blender dev4w1 0-0 "{\"prior\": \"auto\", \"techniques\": \"$O,distortion:every=4\"}"
/tmp/s47/cell.sh $S blender dev4w3 0-0 "{\"prior\": \"auto\", \"techniques\": \"$O,distortion:every=4:weight=3\"}"
/tmp/s47/cell.sh $S blender dev2w1 0-0 "{\"prior\": \"auto\", \"techniques\": \"$O,distortion:every=2\"}"
done
