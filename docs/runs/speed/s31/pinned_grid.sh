#!/bin/bash
# Issue 29's acceptance grid against the pinned f6f2ab9 (session 31): `{"prior": "auto"}` cells of both protocols,
# seeds 0-2, f6f2ab9 then this build (4593621's tree) for each scene and seed, one cell at a time. Completes session
# 30's seed-0 lego and flower pairs (docs/runs/speed/s30/pinned_ab.sh; same work folders, so `bench sparse` skips the
# cells it finds finished). Trees exported with `git archive COMMIT | tar -x -C DIR`, kernels built before.
# COUNTS (seed counts, each round runs the seeds below it) and SCENES (protocol:scene) narrow the grid, e.g.
# pinned_seed2_orbits.sh.
cd /tmp
V='{"auto": {"prior": "auto"}}'
cell() { # tree tag protocol scene nseeds
  PYTHONPATH=$1 OMP_NUM_THREADS=2 /work/main/.venv/bin/python -m gsgs_engine bench sparse --protocol $3 --scene $4 --seeds $5 \
    --variants "$V" --data-root /work/shared/data --work /tmp/f6/w/$2 --doc /tmp/f6/w/$2_$4.md >> /tmp/f6/w/log_$2.txt 2>&1
  echo "$(date +%T) $2 $4 seeds<$5 done" >> /tmp/f6/w/times.txt
}
for n in ${COUNTS:-1 2 3}; do
  for ps in ${SCENES:-blender:blender_lego blender:blender_chair llff:llff_flower llff:llff_horns}; do
    cell /tmp/f6/tree old ${ps%%:*} ${ps#*:} $n
    cell /tmp/s31/tree new ${ps%%:*} ${ps#*:} $n
  done
done
echo "$(date +%T) ${DONE:-grid finished}" >> /tmp/f6/w/times.txt
