#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s45/initcache
F='"absgrad,count_control,dropout:guide=density,binocular:scale=0.5,opacity_decay'
/tmp/s46/cell.sh llff_flower llff dist01 0-0 "{\"prior\": \"auto\", \"techniques\": $F,distortion:weight=0.1\"}"
/tmp/s46/cell.sh llff_horns llff dist01 0-0 "{\"prior\": \"auto\", \"techniques\": $F,distortion:weight=0.1\"}"
