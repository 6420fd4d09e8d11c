#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s45/initcache
ORB='["clone_split","count_control","dropout:max_rate=0.1","binocular:every=2","opacity_decay","unpool"]'
/tmp/s45/cell.sh blender_lego blender unpool 0-0 "{\"prior\": \"auto\", \"techniques\": $ORB}"
/tmp/s45/cell.sh blender_chair blender unpool 0-0 "{\"prior\": \"auto\", \"techniques\": $ORB}"
