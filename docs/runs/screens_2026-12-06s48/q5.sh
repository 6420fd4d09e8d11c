#!/bin/bash
while pgrep -f q4.sh > /dev/null; do sleep 5; done
cd /tmp && PYTHONPATH=/tmp/s48/tree /work/main/.venv/bin/python -m gsgs_engine train /work/shared/data/llff_flower --train-views 29 --iters 2000 --init mvs --out /tmp/s48/dense29 > /tmp/s48/dense29.log 2>&1
echo "$(date +%T) done dense29" >> /tmp/s48/queue.log
