#!/bin/bash
# the 1000-step forward recipe with the binocular view at full size (absgrad kept): never measured together; seed 0
C=/tmp/s42/cell.sh
for S in llff_flower llff_horns; do $C $S llff abfull 0-0 '{"prior": "auto", "techniques": ["absgrad", "count_control", "dropout:guide=density", "binocular", "opacity_decay"]}'; done
echo "$(date +%T) q5 finished" >> /tmp/s42/queue.log
