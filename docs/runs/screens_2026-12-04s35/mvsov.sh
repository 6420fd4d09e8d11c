#!/bin/bash
# session 35 screen: MVS settings overridden (GSGS_MVS_OVERRIDE JSON), LLFF seed 0, one cell at a time
# usage: mvsov.sh TAG JSON [scenes]
TAG=$1; OV=$2; SCENES=${3:-"llff_flower llff_horns"}
for sc in $SCENES; do
  GSGS_MVS_OVERRIDE="$OV" OMP_NUM_THREADS=2 /work/main/.venv/bin/python -m gsgs_engine bench sparse --protocol llff --scene $sc --seeds 1 \
    --variants '{"auto": {"prior": "auto"}}' --data-root /work/shared/data --work /tmp/s35/ov_$TAG --doc /tmp/s35/ov_$TAG/t.md > /tmp/s35/ov_${TAG}_$sc.log 2>&1
  grep -h "PSNR" /tmp/s35/ov_${TAG}_$sc.log | tail -1 | sed "s/^/$TAG $sc /" >> /tmp/s35/ov_results.txt
  grep -h "init:" /tmp/s35/ov_$TAG/llff/$sc/auto/seed0/log.txt | tail -1 | cut -c1-120 >> /tmp/s35/ov_results.txt
done
