#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s45/initcache
while pgrep -f "s47/q5.sh" >/dev/null; do sleep 5; done
O="clone_split,count_control,dropout:max_rate=0.1,binocular:every=2,opacity_decay"
/tmp/s47/cell.sh blender_lego blender fbase 0-0 "{\"prior\": \"auto\", \"iters\": 300, \"techniques\": \"$O\"}"
for S in blender_lego blender_chair; do
/tmp/s47/cell.sh $S blender it1200 0-0 "{\"prior\": \"auto\", \"iters\": 1200}"
done
for R in 3 4; do
/tmp/s47/cell.sh blender_lego blender tbase$R 0-0 "{\"prior\": \"auto\", \"techniques\": \"$O\"}"
/tmp/s47/cell.sh blender_lego blender t8dist$R 0-0 "{\"prior\": \"auto\", \"techniques\": \"$O,distortion:every=8:weight=6\"}"
done
