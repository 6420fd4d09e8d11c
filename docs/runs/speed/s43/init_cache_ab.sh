#!/bin/bash
# the init cache: the same job twice with a fresh cache folder (miss, then hit); after the grid, nothing else running
while pgrep -f "q3[.]sh" > /dev/null; do sleep 5; done
cd /tmp
export GSGS_INIT_CACHE=/tmp/s43/icache
rm -rf /tmp/s43/icache /tmp/s43/ic_*
for run in 1 2; do
  PYTHONPATH=/work/main /work/main/.venv/bin/python -m gsgs_engine bench sparse --protocol blender --scene blender_lego --seeds 0-0 \
    --variants '{"fast": {"prior": "auto", "iters": 300}}' --data-root /work/shared/data --work /tmp/s43/ic_lego$run --doc /tmp/s43/ic_lego$run.md > /tmp/s43/ic_lego$run.log 2>&1
  echo "$(date +%T) lego run $run done" >> /tmp/s43/queue.log
done
for run in 1 2; do
  cd /work/main && GSGS_TIMINGS=/tmp/s43/ic_timings.jsonl /usr/bin/time -f "wall %e s" .venv/bin/python scripts/reconstruct.py --photos /work/shared/data/photos_santorini --out /tmp/s43/ic_santorini$run --preset fast > /tmp/s43/ic_santorini$run.log 2>&1
  echo "$(date +%T) santorini fast run $run done" >> /tmp/s43/queue.log
done
echo "$(date +%T) q4 finished" >> /tmp/s43/queue.log
