#!/bin/bash
# issue 31 screen (session 34): extra L1 weight on the pixels that change over a camera's frames, the 4D model alone, seed 0
cd /tmp
one() { # tag techniques seed core cameras extra
  taskset -c $4 /work/main/.venv/bin/python -m gsgs_engine bench dynamic --data /work/shared/data/panoptic_basketball --cameras $5 --frames 10 \
    --resolution-scale 0.5 --iters 1000 --per-frame-iters 300 --sh-degree 0 --no-lpips --threads 1 --init mvs --techniques $2 \
    --background mean --position-lr-scale 3 --seed $3 $6 --models ${MODELS:-4d} --out /tmp/s34/pan/$1_c$5_s$3 > /tmp/s34/pan/$1_c$5_s$3.log 2>&1
}
echo "$(date +%T) start" >> /tmp/s34/pan/times.txt
one base exposure,dropout,opacity_decay 0 0 6 "" &
one mw1 exposure,dropout,opacity_decay,motion_weight 0 1 6 "" &
wait
echo "$(date +%T) 6 cameras done" >> /tmp/s34/pan/times.txt
one base exposure 0 0 9 "" &
one mw1 exposure,motion_weight 0 1 9 "" &
wait
echo "$(date +%T) 9 cameras done" >> /tmp/s34/pan/times.txt
