#!/bin/bash
# Santorini train job (the reconstruct workflow's), af91a77 (pre-absgrad) and HEAD alternating, one at a time.
J=/tmp/sant/out/jobs/train-20261129-173019/job.json
for round in 1 2; do
  for b in old new; do
    d=/tmp/sant/ab/$b$round; rm -rf $d; mkdir -p $d; cp $J $d/
    if [ $b = old ]; then P=/tmp/old29; else P=/work/main; fi
    echo "$(date +%T) $b$round start" >> /tmp/sant/ab/times.txt
    (cd /tmp && OMP_NUM_THREADS=2 PYTHONPATH=$P /work/main/.venv/bin/python -m gsgs_engine run-job $d > $d/out.txt 2>&1)
    python3 -c "import json; m=json.load(open('$d/result/metrics.json')); print('$b$round', round(m['train_seconds'],1), m['num_gaussians'], m['psnr'] if 'psnr' in m else '')" >> /tmp/sant/ab/times.txt
  done
done
