#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s44/initcache
F='["absgrad", "count_control", "dropout:guide=density", "binocular:scale=0.5:smooth_weight=0.05", "opacity_decay"]'
./cell.sh llff_horns llff sw005 0-0 "{\"prior\": \"auto\", \"techniques\": $F}"
