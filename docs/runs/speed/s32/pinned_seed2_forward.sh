#!/bin/bash
# Session 32: session 31's pinned grid (docs/runs/speed/s31/pinned_grid.sh) completed with LLFF seed 2: f6f2ab9's cell
# and then 4593621's (the build of the grid's other cells; bea9209 trains byte-identical flower PLYs), one cell at a
# time, nothing else running. The same work folders, so the finished seeds 0-1 are skipped.
COUNTS=3 SCENES="llff:llff_flower llff:llff_horns" DONE="forward-facing seed 2 finished" \
  exec "$(dirname "$0")/../s31/pinned_grid.sh"
