#!/bin/bash
# The SH coefficients passed in two parts (no concatenated copy a render) against the build before, side by side:
# the lego and flower protocol jobs (seed 0, `gsgs run-job`, whole jobs: training, export and evaluation), the
# build before (4593621's tree, /tmp/s31/tree) and this one (/tmp/s31/tree_new) alternating, one at a time; lego
# (SH degree 2) twice, flower (degree 0) once.
# Prints train seconds, PSNR and Gaussians, and compares the PLYs byte for byte.
set -u
OUT=${OUT:-/tmp/s31/ab}; mkdir -p $OUT
for round in 1 2; do
  for job in lego flower; do
    [ $job = flower ] && [ $round = 2 ] && continue  # degree 0 there: one pair checks the bits
    for tag in old new; do
      tree=/tmp/s31/tree; [ $tag = new ] && tree=/tmp/s31/tree_new
      d=$OUT/${job}_${tag}_$round; rm -rf $d; mkdir -p $d
      cp /work/main/docs/runs/speed/s26/${job}_job.json $d/job.json
      (cd /tmp && PYTHONPATH=$tree OMP_NUM_THREADS=2 /work/main/.venv/bin/python -m gsgs_engine run-job $d > $d/stdout.txt 2>&1)
      /work/main/.venv/bin/python -c "
import json,sys; m=json.load(open('$d/result/metrics.json'))
print('$(date +%T)', '$job', '$tag', $round, 'train_s %.1f' % m['train_seconds'], 'psnr', m.get('psnr'), 'gaussians', m['num_gaussians'],
      'kernel', {k: round(v, 1) for k, v in (m.get('kernel_seconds') or {}).items()})" | tee -a $OUT/results.txt
    done
    cmp $OUT/${job}_old_$round/result/point_cloud.ply $OUT/${job}_new_$round/result/point_cloud.ply \
      && echo "$job round $round: PLYs identical" | tee -a $OUT/results.txt
  done
done
