#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s45/initcache
while pgrep -f "s47/q2.sh" >/dev/null; do sleep 5; done
O="clone_split,count_control,dropout:max_rate=0.1,binocular:every=2,opacity_decay"
for R in 1 2; do
/tmp/s47/cell.sh blender_lego blender tbase$R 0-0 "{\"prior\": \"auto\", \"techniques\": \"$O\"}"
/tmp/s47/cell.sh blender_lego blender tdist$R 0-0 "{\"prior\": \"auto\", \"techniques\": \"$O,distortion:every=4:weight=3\"}"
done
