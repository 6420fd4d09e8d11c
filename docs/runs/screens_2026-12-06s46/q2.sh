#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s45/initcache
while pgrep -f "q1.sh" >/dev/null; do sleep 10; done
F='"absgrad,count_control,dropout:guide=density,binocular:scale=0.5,opacity_decay'
/tmp/s46/cell.sh llff_flower llff dist1 0-0 "{\"prior\": \"auto\", \"techniques\": $F,distortion:weight=1.0\"}"
/tmp/s46/cell.sh llff_flower llff dist10 0-0 "{\"prior\": \"auto\", \"techniques\": $F,distortion:weight=10.0\"}"
