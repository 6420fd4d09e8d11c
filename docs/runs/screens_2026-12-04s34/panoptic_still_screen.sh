#!/bin/bash
# issue 31 screen (session 34): the room as one stillall set (GSGS_STILL_ROOM=1 scratch build), the 4D model alone
cd /tmp
while pgrep -f full.sh > /dev/null; do sleep 5; done
one() { # tag cameras techniques seed core extra
  env $TAGENV taskset -c $5 /work/main/.venv/bin/python -m gsgs_engine bench dynamic --data /work/shared/data/panoptic_basketball --cameras $2 --frames 10 \
    --resolution-scale 0.5 --iters 1000 --per-frame-iters 300 --sh-degree 0 --no-lpips --threads 1 --init mvs --techniques $3 \
    --background mean --position-lr-scale 3 --seed $4 $6 --models 4d --out /tmp/s34/pan/$1_c$2_s$4 > /tmp/s34/pan/$1_c$2_s$4.log 2>&1
}
TAGENV="GSGS_STILL_ROOM=1 GSGS_STILL_ALL=1"
one stillall 3 exposure,dropout,opacity_decay 0 0 "--rig inward" &
one stillall 6 exposure,dropout,opacity_decay 0 1 "" &
wait
echo "$(date +%T) stillall seed 0 done" >> /tmp/s34/pan/still_times.txt
