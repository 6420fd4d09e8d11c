#!/bin/bash
# pinned_grid.sh's seed 2 for the NeRF-synthetic scenes only (after the session's CI run, nothing else running).
COUNTS=3 SCENES="blender:blender_lego blender:blender_chair" DONE="orbit seed 2 finished" \
  exec "$(dirname "$0")/pinned_grid.sh"
