#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s44/initcache
A='{"prior": "auto"}'
OV='{"window": 5, "num_depths": 192, "sweep_budget": 2e8}'
for s in blender_lego blender_chair; do GSGS_MVS_OVERRIDE="$OV" ./cell.sh $s blender w5d192 0-0 "$A"; done
for k in 1 2; do for s in llff_flower llff_horns; do
  GSGS_MVS_OVERRIDE="$OV" ./cell.sh $s llff w5d192 $k-$k "$A"
  ./cell.sh $s llff base $k-$k "$A"
done; done
