#!/bin/bash
# session 35: Panoptic frame 0, 9 cameras, --prior auto (the photos' mean colour behind the splats) against the same with
# the background sphere; one thread each, pinned one per core, side by side
cd /tmp
run() { # core tag extra
  OMP_NUM_THREADS=1 taskset -c $1 env PYTHONPATH=/tmp/s35/tree2 /work/main/.venv/bin/python -m gsgs_engine train /work/shared/data/panoptic_basketball \
    --train-views 9 --frames 0 --prior auto --iters 1000 --seed 0 --out /tmp/s35/frame0_$2 $3 > /tmp/s35/frame0_$2.log 2>&1
}
run 0 mean "" & run 1 sphere "--effects background=sphere" & wait
