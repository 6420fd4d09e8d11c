#!/bin/bash
# usage: cell.sh SCENE PROTOCOL TAG SEEDS 'VARIANTJSON' [TREE]
S=$1; P=$2; TAG=$3; SEEDS=$4; V=$5; TREE=${6:-/tmp/s49/tree}
cd /tmp && PYTHONPATH=$TREE /work/main/.venv/bin/python -m gsgs_engine bench sparse --protocol $P --scene $S --seeds $SEEDS \
  --variants "{\"$TAG\": $V}" --data-root /work/shared/data --work /tmp/s49/runs --doc /tmp/s49/runs/${S}_${TAG}_${SEEDS}.md > /tmp/s49/runs/${S}_${TAG}_${SEEDS}.log 2>&1
echo "$(date +%T) done $S $TAG $SEEDS rc=$?" >> /tmp/s49/queue.log
