#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s44/initcache
for sw in 0.2 0.0; do tag=sw${sw/./}
F="[\"absgrad\", \"count_control\", \"dropout:guide=density\", \"binocular:scale=0.5:smooth_weight=$sw\", \"opacity_decay\"]"
for s in llff_flower llff_horns; do ./cell.sh $s llff $tag 0-0 "{\"prior\": \"auto\", \"techniques\": $F}"; done
done
