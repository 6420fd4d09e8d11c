#!/bin/bash
one() { # plr core tag
  taskset -c $2 /work/main/.venv/bin/python -m gsgs_engine bench dynamic --data /work/shared/data/panoptic_basketball --cameras 3 --frames 10 \
    --resolution-scale 0.5 --iters 1000 --per-frame-iters 300 --sh-degree 0 --no-lpips --threads 1 --init mvs --techniques exposure,dropout,opacity_decay \
    --background mean --position-lr-scale $1 --seed 0 --rig inward --models 4d --out /tmp/s35/pan/plr$1 > /tmp/s35/pan/plr$1.log 2>&1
}
one 0.3 0 & one 1 1 & wait
