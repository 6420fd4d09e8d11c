#!/bin/bash
# more seeds of the orbit cells, the two builds alternating cell by cell (quality: is the change noise? time: pairs)
while pgrep -f "s27/extra.sh" >/dev/null; do sleep 10; done
cd /tmp
for seed in 3 4; do for scene in llff_horns llff_flower; do for b in head new; do
  echo "$(date +%T) start $scene $seed $b" >> /tmp/s27/extra/times.txt
  PYTHONPATH=/tmp/s27/$b OMP_NUM_THREADS=2 /work/main/.venv/bin/python -m gsgs_engine bench sparse --protocol llff --scene $scene --seeds $seed-$seed \
    --variants '{"auto": {"prior": "auto"}}' --data-root /work/shared/data --work /tmp/s27/extra/$b/$scene --doc /tmp/s27/extra/$b/$scene.md > /tmp/s27/extra/$b-$scene-$seed.log 2>&1
  echo "$(date +%T) end $scene $seed $b rc=$?" >> /tmp/s27/extra/times.txt
done; done; done
