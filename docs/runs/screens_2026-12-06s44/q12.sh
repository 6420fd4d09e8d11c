#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s44/initcache
F='["absgrad", "count_control", "dropout:guide=density", "binocular:scale=0.5:smooth_weight=0.1", "opacity_decay"]'
for k in 1 2; do for s in llff_flower llff_horns; do ./cell.sh $s llff sw01 $k-$k "{\"prior\": \"auto\", \"techniques\": $F}"; done; done
