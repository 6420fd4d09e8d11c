#!/bin/bash
# Session 34: OpenMP wait policy again on this VM: steps 1-300 of the lego protocol job, alternating.
cd /tmp
J=/tmp/s34/spin/lego
for round in 1 2 3; do
  for cfg in passive spin30k spin300k spin1m; do
    rm -rf $J; mkdir -p $J; cp /tmp/s34/c2f/blender/blender_lego/auto/seed0/job.json $J/
    case $cfg in
      passive) ENVV="" ;;
      spin30k) ENVV="GOMP_SPINCOUNT=30000" ;;
      spin300k) ENVV="GOMP_SPINCOUNT=300000" ;;
      spin1m) ENVV="GOMP_SPINCOUNT=1000000" ;;
    esac
    env $ENVV TAG=$cfg OMP_NUM_THREADS=2 /work/main/.venv/bin/python /work/main/docs/runs/speed/s26/upto.py 300 $J 2>/dev/null | grep RESULT >> /tmp/s34/spin/results.txt
  done
done
echo done >> /tmp/s34/spin/results.txt
