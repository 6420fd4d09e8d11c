#!/bin/bash
cd /tmp
T=/tmp/s29/abs
run() { # protocol scene tag variant
  PYTHONPATH=$T OMP_NUM_THREADS=2 /work/main/.venv/bin/python -m gsgs_engine bench sparse --protocol $1 --scene $2 --seeds ${SEEDS:-1} \
    --variants "$4" --data-root /work/shared/data --work /tmp/s29/w/$3 --doc /tmp/s29/w/$3/doc_$2.md > /tmp/s29/w/log_$3_$2_b.txt 2>&1
}
FWD='"count_control", "dropout:guide=density", "binocular:scale=0.5", "opacity_decay"'
SEEDS=6 run llff llff_flower abs4 "{\"abs4\": {\"prior\": \"auto\", \"techniques\": [\"absgrad\", $FWD]}}"
SEEDS=6 run llff llff_horns abs4 "{\"abs4\": {\"prior\": \"auto\", \"techniques\": [\"absgrad\", $FWD]}}"
echo done
