#!/bin/bash
# 4D model alone at 3 cameras, seed 0, shorter schedules (session 35)
one() { # iters core
  taskset -c $2 /work/main/.venv/bin/python -m gsgs_engine bench dynamic --data /work/shared/data/panoptic_basketball --cameras 3 --frames 10 \
    --resolution-scale 0.5 --iters $1 --per-frame-iters 300 --sh-degree 0 --no-lpips --threads 1 --init mvs --techniques exposure,dropout,opacity_decay \
    --background mean --position-lr-scale 3 --seed 0 --rig inward --models 4d --out /tmp/s35/pan/short$1 > /tmp/s35/pan/short$1.log 2>&1
}
one 100 0 & one 150 1 & wait
one 200 0 & one 50 1 & wait
