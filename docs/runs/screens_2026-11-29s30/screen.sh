#!/bin/bash
# issue 30 screen (session 30): the forward-facing recipe with absolute gradients, two levers, seed 0, one cell at a
# time, from an exported tree of c9f96c6 (git archive c9f96c6 | tar -x -C /tmp/s30/tree).
cd /tmp
T=/tmp/s30/tree
mkdir -p /tmp/s30/w
run() { # protocol scene tag variant
  PYTHONPATH=$T OMP_NUM_THREADS=2 /work/main/.venv/bin/python -m gsgs_engine bench sparse --protocol $1 --scene $2 --seeds ${SEEDS:-1} \
    --variants "$4" --data-root /work/shared/data --work /tmp/s30/w/$3 --doc /tmp/s30/w/$3/doc_$2.md > /tmp/s30/w/log_$3_$2.txt 2>&1
}
REST='"dropout:guide=density", "binocular:scale=0.5", "opacity_decay"'
# a 30 % larger Gaussian budget (0.13 per training pixel, not 0.1): absolute gradients may spend it better than 3DGS's
run llff llff_flower b13 "{\"b13\": {\"prior\": \"auto\", \"techniques\": [\"absgrad\", \"count_control:per_pixel=0.13\", $REST]}}"
run llff llff_horns b13 "{\"b13\": {\"prior\": \"auto\", \"techniques\": [\"absgrad\", \"count_control:per_pixel=0.13\", $REST]}}"
# the absolute-gradient threshold at 3 x 3DGS's (not 4)
run llff llff_flower t3 "{\"t3\": {\"prior\": \"auto\", \"techniques\": [\"absgrad:threshold=3\", \"count_control\", $REST]}}"
run llff llff_horns t3 "{\"t3\": {\"prior\": \"auto\", \"techniques\": [\"absgrad:threshold=3\", \"count_control\", $REST]}}"
echo done
