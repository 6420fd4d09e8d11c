#!/bin/bash
# issue 31 status on this VM (session 34): every model, 3 / 6 / 9 cameras, seeds 0-2, the recipe of each rig, two runs at a time (one thread pinned to each core)
# PER_FRAME_ITERS (300), MODELS (every model) and TAG (full) change the per-frame steps, the models and the output names (pf100.sh)
cd /tmp
one() { # cameras techniques seed core extra
  taskset -c $4 /work/main/.venv/bin/python -m gsgs_engine bench dynamic --data /work/shared/data/panoptic_basketball --cameras $1 --frames 10 \
    --resolution-scale 0.5 --iters 1000 --per-frame-iters ${PER_FRAME_ITERS:-300} --sh-degree 0 --no-lpips --threads 1 --init mvs --techniques $2 \
    --background mean --position-lr-scale 3 --seed $3 $5 ${MODELS:+--models $MODELS} --out /tmp/s34/pan/${TAG:-full}_c$1_s$3 > /tmp/s34/pan/${TAG:-full}_c$1_s$3.log 2>&1
}
T3=exposure,dropout,opacity_decay; T6=exposure,dropout,opacity_decay; T9=exposure
jobs_list=("3 $T3 0 --rig inward" "3 $T3 1 --rig inward" "3 $T3 2 --rig inward" "6 $T6 0" "6 $T6 1" "6 $T6 2" "9 $T9 0" "9 $T9 1" "9 $T9 2")
i=0
while [ $i -lt ${#jobs_list[@]} ]; do
  set -- ${jobs_list[$i]}; one $1 $2 $3 0 "$4 $5" &
  j=$((i+1))
  if [ $j -lt ${#jobs_list[@]} ]; then set -- ${jobs_list[$j]}; one $1 $2 $3 1 "$4 $5" & fi
  wait
  echo "$(date +%T) runs $i-$j done" >> /tmp/s34/pan/${TAG:-full}_times.txt
  i=$((i+2))
done
echo "$(date +%T) all done" >> /tmp/s34/pan/${TAG:-full}_times.txt
