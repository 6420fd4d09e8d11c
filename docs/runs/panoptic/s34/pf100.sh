#!/bin/bash
# issue 31 (session 34): the per-frame static baseline at the 4D model's total steps (10 frames x 100 = 1000), seeds 0-2, 3 / 6 / 9 cameras
PER_FRAME_ITERS=100 MODELS=static_per_frame TAG=pf100 exec bash "$(dirname "$0")/full.sh"
