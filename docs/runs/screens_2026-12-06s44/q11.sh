#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s44/initcache
for sw in 0.1 0.025; do tag=sw${sw/./}
F="[\"absgrad\", \"count_control\", \"dropout:guide=density\", \"binocular:scale=0.5:smooth_weight=$sw\", \"opacity_decay\"]"
for s in llff_horns llff_flower; do ./cell.sh $s llff $tag 0-0 "{\"prior\": \"auto\", \"techniques\": $F}"; done
done
