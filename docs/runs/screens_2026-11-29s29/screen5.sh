#!/bin/bash
cd /tmp
T=/tmp/s29/abs
run() { # protocol scene tag variant
  PYTHONPATH=$T OMP_NUM_THREADS=2 /work/main/.venv/bin/python -m gsgs_engine bench sparse --protocol $1 --scene $2 --seeds ${SEEDS:-1} \
    --variants "$4" --data-root /work/shared/data --work /tmp/s29/w/$3 --doc /tmp/s29/w/$3/doc_$2.md > /tmp/s29/w/log_$3_$2_b.txt 2>&1
}
ORBIT='"count_control", "dropout:max_rate=0.1", "binocular:every=2", "opacity_decay"'
SEEDS=3 run blender blender_lego abs3 "{\"abs3\": {\"prior\": \"auto\", \"techniques\": [\"absgrad:threshold=3\", $ORBIT]}}"
SEEDS=3 run blender blender_chair abs3 "{\"abs3\": {\"prior\": \"auto\", \"techniques\": [\"absgrad:threshold=3\", $ORBIT]}}"
echo done
