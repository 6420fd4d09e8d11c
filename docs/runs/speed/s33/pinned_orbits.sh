#!/bin/bash
# Issue 29 on this session's VM (AMD EPYC with AVX-512, 2 cores): `{"prior": "auto"}` NeRF-synthetic cells, seeds
# 0-2, f6f2ab9 then this build (ef7c4f1's tree: the engine of 51e560c) for each scene and seed, one cell at a time,
# nothing else running (--seeds N: the first N seeds, as f6f2ab9 takes it; finished cells are skipped). Trees exported with `git archive COMMIT | tar -x -C DIR`, kernels built before.
cd /tmp
V='{"auto": {"prior": "auto"}}'
cell() { # tree tag protocol scene seed
  PYTHONPATH=$1 OMP_NUM_THREADS=2 /work/main/.venv/bin/python -m gsgs_engine bench sparse --protocol $3 --scene $4 --seeds $(( $5 + 1 )) \
    --variants "$V" --data-root /work/shared/data --work /tmp/s33/pin/$2 --doc /tmp/s33/pin/$2_$4_$5.md >> /tmp/s33/pin/log_$2.txt 2>&1
  echo "$(date +%T) $2 $4 seed $5 done" >> /tmp/s33/pin/times.txt
}
mkdir -p /tmp/s33/pin
for s in ${SEEDS:-0 1 2}; do
  for ps in ${SCENES:-blender:blender_lego blender:blender_chair}; do
    cell /tmp/f6/tree old ${ps%%:*} ${ps#*:} $s
    cell /tmp/s33/new new ${ps%%:*} ${ps#*:} $s
  done
done
echo "$(date +%T) grid finished" >> /tmp/s33/pin/times.txt
