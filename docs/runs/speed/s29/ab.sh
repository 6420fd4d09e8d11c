#!/bin/bash
# whole trainings (steps 1..1000 of gsgs run-job, no evaluation) of the flower protocol job: af91a77 (old) and 601afab (head, absgrad in the forward recipe), alternating
cd /tmp
mkdir -p /tmp/s29/ab
for round in 1 2; do
  for build in old head; do
    d=/tmp/s29/ab/flower_${build}_r$round; rm -rf $d; mkdir -p $d
    cp /tmp/s29/flower_job.json $d/job.json
    TAG="flower $build r$round" PYTHONPATH=/tmp/s29/$build OMP_NUM_THREADS=2 /work/main/.venv/bin/python /work/main/docs/runs/speed/s26/upto.py 1000 $d 2>/dev/null | grep RESULT | sed "s/^/$(date +%T) /" >> /tmp/s29/ab/results.txt
  done
done
