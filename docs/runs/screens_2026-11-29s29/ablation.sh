#!/bin/bash
# session 29: absgrad alone on the dense init (plain 3DGS otherwise) against the dense init, seed 0, beside a CI run (no seconds compared)
cd /tmp
T=/tmp/s29/head
for p in "blender blender_lego" "blender blender_chair" "llff llff_flower" "llff llff_horns"; do
  set -- $p
  PYTHONPATH=$T OMP_NUM_THREADS=2 /work/main/.venv/bin/python -m gsgs_engine bench sparse --protocol $1 --scene $2 --seeds 1 \
    --variants '{"3dgs (dense init)": {"prior": "none", "init": "mvs"}, "dense + absgrad": {"prior": "none", "init": "mvs", "techniques": ["absgrad"]}}' \
    --data-root /work/shared/data --work /tmp/s29/w/abl --doc /tmp/s29/w/abl/doc_$2.md > /tmp/s29/w/log_abl_$2.txt 2>&1
done
echo done
