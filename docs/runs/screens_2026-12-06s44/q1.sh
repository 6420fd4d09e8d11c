#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s44/initcache
F='["absgrad", "count_control", "dropout:guide=density", "binocular:scale=0.5", "opacity_decay", "coregularisation"]'
./cell.sh llff_flower llff cor 0-0 "{\"prior\": \"auto\", \"techniques\": $F}"
./cell.sh llff_horns llff cor 0-0 "{\"prior\": \"auto\", \"techniques\": $F}"
