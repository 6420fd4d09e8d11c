#!/bin/bash
# issue 31 screen (session 29): absgrad in the 4D recipe at 3 cameras, the 4D model alone, seeds 0-2 (two side by side, one core each)
cd /tmp
one() { # tag techniques seed core cameras
  PYTHONPATH=/tmp/s29/abs taskset -c $4 /work/main/.venv/bin/python -m gsgs_engine bench dynamic --data /work/shared/data/panoptic_basketball --cameras $5 --frames 10 \
    --resolution-scale 0.5 --iters 1000 --per-frame-iters 300 --sh-degree 0 --no-lpips --threads 1 --init mvs --techniques $2 \
    --background mean --position-lr-scale 3 --seed $3 $RIG --models 4d --out /tmp/s29/pan/$1_s$3 > /tmp/s29/pan/$1_s$3.log 2>&1
}
while pgrep -f "screen5.sh|after4.sh" > /dev/null; do sleep 10; done
RIG="--rig inward"
echo "$(date +%T) start" >> /tmp/s29/pan/times.txt
one abs_c3 absgrad,exposure,dropout,opacity_decay 0 0 3 &
one abs_c3 absgrad,exposure,dropout,opacity_decay 1 1 3 &
wait
echo "$(date +%T) pair 1" >> /tmp/s29/pan/times.txt
one abs_c3 absgrad,exposure,dropout,opacity_decay 2 0 3 &
wait
echo "$(date +%T) done" >> /tmp/s29/pan/times.txt
