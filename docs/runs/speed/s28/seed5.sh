#!/bin/bash
# LLFF seed 5 of cf100e1 (torch binocular term) and of the compiled term, alternating
cd /tmp
for s in llff_flower llff_horns; do
  for b in main fused; do
    echo "$(date +%T) start $s $b" >> /tmp/s28/s5/times.txt
    PYTHONPATH=/tmp/s28/$b OMP_NUM_THREADS=2 /work/main/.venv/bin/python -m gsgs_engine bench sparse --protocol llff --scene $s --seeds 5-5 \
      --variants '{"auto": {"prior": "auto"}}' --data-root /work/shared/data --work /tmp/s28/s5/$b/$s --doc /tmp/s28/s5/$b/$s.md >> /tmp/s28/s5/$b.log 2>&1
  done
done
echo "$(date +%T) done" >> /tmp/s28/s5/times.txt
