#!/bin/bash
C=/tmp/s40/cell.sh
O='"clone_split", "count_control", "dropout:max_rate=0.1", "binocular:every=2", "opacity_decay"'
for S in blender_lego blender_chair; do
  $C $S blender planned 1 '{"prior": "auto"}'
  $C $S blender nocc 1 '{"prior": "auto", "techniques": ["clone_split", "dropout:max_rate=0.1", "binocular:every=2", "opacity_decay"]}'
  $C $S blender nodrop 1 '{"prior": "auto", "techniques": ["clone_split", "count_control", "binocular:every=2", "opacity_decay"]}'
  $C $S blender nobino 1 '{"prior": "auto", "techniques": ["clone_split", "count_control", "dropout:max_rate=0.1", "opacity_decay"]}'
  $C $S blender nodecay 1 '{"prior": "auto", "techniques": ["clone_split", "count_control", "dropout:max_rate=0.1", "binocular:every=2"]}'
  $C $S blender sfminit 1 '{"prior": "auto", "init": "sfm"}'
  $C $S blender poslr1 1 '{"prior": "auto", "position_lr_scale": 1.0}'
done
F='"absgrad", "count_control", "dropout:guide=density", "binocular:scale=0.5", "opacity_decay"'
for S in llff_flower llff_horns; do
  $C $S llff planned 1 '{"prior": "auto"}'
  $C $S llff nobino 1 '{"prior": "auto", "techniques": ["absgrad", "count_control", "dropout:guide=density", "opacity_decay"]}'
  $C $S llff nopseudo 1 '{"prior": "auto", "effects": {"pseudo_views": "off"}}'
  $C $S llff nodrop 1 '{"prior": "auto", "techniques": ["absgrad", "count_control", "binocular:scale=0.5", "opacity_decay"]}'
  $C $S llff nodecay 1 '{"prior": "auto", "techniques": ["absgrad", "count_control", "dropout:guide=density", "binocular:scale=0.5"]}'
  $C $S llff sfminit 1 '{"prior": "auto", "init": "sfm"}'
  $C $S llff nocc 1 '{"prior": "auto", "techniques": ["absgrad", "dropout:guide=density", "binocular:scale=0.5", "opacity_decay"]}'
done
echo "$(date +%T) q1 finished" >> /tmp/s40/queue.log
