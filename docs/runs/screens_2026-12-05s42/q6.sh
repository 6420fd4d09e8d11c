#!/bin/bash
# seeds 1-2 of abfull (the 1000-step forward recipe with the binocular view at full size; seed 0: 20.68 -> 20.75 dB)
C=/tmp/s42/cell.sh
for SEED in 1 2; do
for S in llff_flower llff_horns; do $C $S llff abfull $SEED-$SEED '{"prior": "auto", "techniques": ["absgrad", "count_control", "dropout:guide=density", "binocular", "opacity_decay"]}'; done; done
echo "$(date +%T) q6 finished" >> /tmp/s42/queue.log
