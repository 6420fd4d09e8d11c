#!/bin/bash
# issue 31 screen (session 28): the binocular view in the 4D recipe at 3 cameras, the 4D model alone, seeds 0-2; results in /tmp/s28/pan, copied here as {base,bino}_c3_sS.json
cd /tmp
one() { # tag techniques seed
  taskset -c $4 /work/main/.venv/bin/python -m gsgs_engine bench dynamic --data /work/shared/data/panoptic_basketball --cameras 3 --frames 10 \
    --resolution-scale 0.5 --iters 1000 --per-frame-iters 300 --sh-degree 0 --no-lpips --threads 1 --init mvs --techniques $2 \
    --background mean --position-lr-scale 3 --seed $3 --rig inward --models 4d --out /tmp/s28/pan/$1_s$3 > /tmp/s28/pan/$1_s$3.log 2>&1
}
for s in 0 1 2; do
  echo "$(date +%T) seed $s" >> /tmp/s28/pan/times.txt
  one base exposure,dropout,opacity_decay $s 0 &
  one bino exposure,dropout,opacity_decay,binocular $s 1 &
  wait
done
echo "$(date +%T) done" >> /tmp/s28/pan/times.txt
