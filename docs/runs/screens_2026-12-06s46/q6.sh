#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s45/initcache
O='"clone_split,count_control,dropout:max_rate=0.1,binocular:every=2,opacity_decay'
for W in 0.1 1.0; do
/tmp/s46/cell.sh blender_lego blender odist$W 0-0 "{\"prior\": \"auto\", \"techniques\": $O,distortion:weight=$W\"}"
/tmp/s46/cell.sh blender_chair blender odist$W 0-0 "{\"prior\": \"auto\", \"techniques\": $O,distortion:weight=$W\"}"
done
