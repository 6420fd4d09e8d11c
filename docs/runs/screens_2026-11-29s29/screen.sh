#!/bin/bash
# issue 30 screen (session 29): absgrad in the recipes, seed 0, one cell at a time
cd /tmp
T=/tmp/s29/abs
run() { # protocol scene tag variant
  PYTHONPATH=$T OMP_NUM_THREADS=2 /work/main/.venv/bin/python -m gsgs_engine bench sparse --protocol $1 --scene $2 --seeds ${SEEDS:-1} \
    --variants "$4" --data-root /work/shared/data --work /tmp/s29/w/$3 --doc /tmp/s29/w/$3/doc_$2.md > /tmp/s29/w/log_$3_$2.txt 2>&1
}
ORBIT='"count_control", "dropout:max_rate=0.1", "binocular:every=2", "opacity_decay"'
FWD='"count_control", "dropout:guide=density", "binocular:scale=0.5", "opacity_decay"'
run blender blender_lego abs4 "{\"abs4\": {\"prior\": \"auto\", \"techniques\": [\"absgrad\", $ORBIT]}}"
run blender blender_chair abs4 "{\"abs4\": {\"prior\": \"auto\", \"techniques\": [\"absgrad\", $ORBIT]}}"
run llff llff_flower abs4 "{\"abs4\": {\"prior\": \"auto\", \"techniques\": [\"absgrad\", $FWD]}}"
run llff llff_horns abs4 "{\"abs4\": {\"prior\": \"auto\", \"techniques\": [\"absgrad\", $FWD]}}"
echo done
