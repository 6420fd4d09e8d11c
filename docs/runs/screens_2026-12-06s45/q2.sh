#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s45/initcache
while pgrep -f "s45/q1.sh" > /dev/null; do sleep 10; done
ORB='["clone_split","count_control","dropout:max_rate=0.1","binocular:every=2","opacity_decay","unpool:ratio=6:min_opacity=0.5"]'
/tmp/s45/cell.sh blender_lego blender up6o5 0-0 "{\"prior\": \"auto\", \"techniques\": $ORB}"
/tmp/s45/cell.sh blender_chair blender up6o5 0-0 "{\"prior\": \"auto\", \"techniques\": $ORB}"
