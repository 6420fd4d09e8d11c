#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s48/initcache
C=/tmp/s48/cell.sh
while pgrep -f q5.sh > /dev/null; do sleep 5; done
$C blender_lego blender base 0-0 '{"prior": "auto"}'
GSGS_MVS_OVERRIDE='{"sgm_paths": 8}' $C blender_lego blender sgm8 0-0 '{"prior": "auto"}' /tmp/s48/tree2
$C blender_chair blender base 0-0 '{"prior": "auto"}'
GSGS_MVS_OVERRIDE='{"sgm_paths": 8}' $C blender_chair blender sgm8 0-0 '{"prior": "auto"}' /tmp/s48/tree2
