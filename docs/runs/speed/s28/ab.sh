#!/bin/bash
# whole trainings (steps 1..1000 of gsgs run-job, no evaluation) of cf100e1 (main) and s28b (fused binocular), alternating
cd /tmp
for round in 1 2; do
  for scene in lego flower; do
    for build in main fused; do
      d=/tmp/s28/ab/${scene}_${build}_r$round; rm -rf $d; mkdir -p $d
      cp /tmp/s28/${scene}_job.json $d/job.json
      TAG="$scene $build r$round" PYTHONPATH=/tmp/s28/$build OMP_NUM_THREADS=2 /work/main/.venv/bin/python /work/main/docs/runs/speed/s26/upto.py 1000 $d 2>/dev/null | grep RESULT | sed "s/^/$(date +%T) /" >> /tmp/s28/ab/results.txt
    done
  done
done
