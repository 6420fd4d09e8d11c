#!/bin/bash
# issue 31 (session 34): dropout to 0.4 (not 0.2) in the recipe, every model, 3 cameras seeds 0-2; the per-frame baseline at 100 steps too; 6 cameras 4D seeds 1-2
cd /tmp
run() { # tag cameras seed core per_frame_iters models extra
  taskset -c $4 /work/main/.venv/bin/python -m gsgs_engine bench dynamic --data /work/shared/data/panoptic_basketball --cameras $2 --frames 10 \
    --resolution-scale 0.5 --iters 1000 --per-frame-iters $5 --sh-degree 0 --no-lpips --threads 1 --init mvs \
    --techniques exposure,dropout:max_rate=0.4,opacity_decay --background mean --position-lr-scale 3 --seed $3 $7 --models $6 \
    --out /tmp/s34/pan/$1_c$2_s$3 > /tmp/s34/pan/$1_c$2_s$3.log 2>&1
}
run d04all 3 0 0 300 4d,static_all,static_per_frame "--rig inward" &
run d04all 3 1 1 300 4d,static_all,static_per_frame "--rig inward" &
wait
run d04all 3 2 0 300 4d,static_all,static_per_frame "--rig inward" &
( run d04pf100 3 0 1 100 static_per_frame "--rig inward"; run d04pf100 3 1 1 100 static_per_frame "--rig inward"; run d04pf100 3 2 1 100 static_per_frame "--rig inward" ) &
wait
run drop04 6 1 0 300 4d "" &
run drop04 6 2 1 300 4d "" &
wait
echo "$(date +%T) done" >> /tmp/s34/pan/drop04_times.txt
