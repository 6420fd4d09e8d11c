#!/bin/bash
# quiet window: nothing else running. lego + flower auto, this build (HEAD export) then f6f2ab9, alternating
cd /tmp/s16/q
PY=/work/main/.venv/bin/python
log=/tmp/s16/quiet.log
echo "start $(date +%T)" > $log
PYTHONPATH=/tmp/s16/h1 $PY -m gsgs_engine bench machine >> $log 2>&1
rm -rf /tmp/s16/q/cells
for pair in "blender blender_lego" "llff llff_flower"; do
set -- $pair
PYTHONPATH=/tmp/s16/h1 $PY -m gsgs_engine bench sparse --protocol $1 --scene $2 --seeds 1 \
  --variants '{"auto": {"prior": "auto"}}' --data-root /work/shared/data --work /tmp/s16/q/cells/new --doc /tmp/s16/q/new_$2.md >> $log 2>&1
echo "new $2 done $(date +%T)" >> $log
PYTHONPATH=/tmp/old_f6 $PY -m gsgs_engine bench sparse --protocol $1 --scene $2 --seeds 1 \
  --variants '{"auto": {"prior": "auto"}}' --data-root /work/shared/data --work /tmp/s16/q/cells/old --doc /tmp/s16/q/old_$2.md >> $log 2>&1
echo "old $2 done $(date +%T)" >> $log
done
PYTHONPATH=/tmp/s16/h1 $PY -m gsgs_engine bench machine >> $log 2>&1
echo QUIETDONE >> $log
