#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s45/initcache
for S in blender_lego blender_chair; do
/tmp/s47/cell.sh $S blender L3kbase 0-0 "{\"prior\": \"auto\", \"iters\": 3000}" /tmp/s47/tree2
/tmp/s47/cell.sh $S blender L3kdist 0-0 "{\"prior\": \"auto\", \"iters\": 3000, \"techniques\": \"clone_split,count_control,dropout,binocular,opacity_decay,distortion\"}" /tmp/s47/tree2
done
