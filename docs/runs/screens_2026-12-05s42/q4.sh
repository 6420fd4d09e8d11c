#!/bin/bash
# the plan's triangulation without SIFT domain-size pooling (S42_DSP=0 in the scratch tree's sfm.py: about half the
# triangulation's seconds), --prior auto at 1000 steps, seed 0, all four scenes
C=/tmp/s42/cell.sh
for S in blender_lego blender_chair; do S42_DSP=0 $C $S blender nodsp 0-0 '{"prior": "auto"}'; done
for S in llff_flower llff_horns; do S42_DSP=0 $C $S llff nodsp 0-0 '{"prior": "auto"}'; done
echo "$(date +%T) q4 finished" >> /tmp/s42/queue.log
