#!/bin/bash
# Device grid: the issue-29 reduced-render variants x LLFF scenes x 3 seeds on CUDA (gsplat).
# usage: bash .dev/grid.sh PROTOCOL DEADLINE_S SCENES...
proto=$1; deadline=$2; shift 2; scenes="$@"
t0=$(date +%s)
el() { echo "[$(( $(date +%s) - t0 )) s] $*"; }
export PYTHONUNBUFFERED=1 OMP_NUM_THREADS=2 OMP_WAIT_POLICY=PASSIVE
if [ ! -d /tmp/site/pycolmap ]; then mkdir -p /tmp/site && tar -xJf .dev/site.tar.xz -C /tmp/site || exit 3; fi
export PYTHONPATH=/tmp/site:$PWD
el "site ready"
mkdir -p /tmp/data
if [ -d .dev/llff ]; then python3 - <<'PY'
import cv2, os, shutil, numpy as np
for scene in os.listdir(".dev/llff"):
    d = f"/tmp/data/{scene}"; os.makedirs(f"{d}/images_8", exist_ok=True)
    shutil.copy(f".dev/llff/{scene}/poses_bounds.npy", d)
    for f in os.listdir(f".dev/llff/{scene}/images_8"):
        im = cv2.imdecode(np.fromfile(f".dev/llff/{scene}/images_8/{f}", np.uint8), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(f"{d}/images_8/{f[:-5]}", im)
PY
fi
[ -d .dev/blender ] && cp -r .dev/blender/* /tmp/data/
ls /tmp/data; el "data ready"
nvidia-smi -L
python3 -c "import torch, pycolmap, gsplat, numpy, cv2; print(torch.__version__, pycolmap.__version__, gsplat.__version__, numpy.__version__, cv2.__version__)" || exit 4
python3 -c "from gsplat.cuda._backend import _C; print('gsplat kernels', _C is not None)" 2>&1 | tail -2
el "gsplat built"
V=.dev/variants_$proto.json
first=$(echo $scenes | cut -d' ' -f1)
python3 -m gsgs_engine bench sparse --protocol $proto --scene $first --data-root /tmp/data --variants '{"smoke": {"prior": "auto", "backend": "cuda"}}' --seeds 1 --iters 60 --work /tmp/smoke --doc /tmp/smoke/t.md > /tmp/smoke.log 2>&1
if [ $? -ne 0 ] || ! grep -q '"state": "ok"' /tmp/smoke/$proto/$first/smoke/seed0/status.json 2>/dev/null; then
  tail -30 /tmp/smoke.log; tail -60 /tmp/smoke/$proto/$first/smoke/seed0/bench_log.txt; cp /tmp/smoke/$proto/$first/smoke/seed0/bench_log.txt $OUT/smoke_log.txt; exit 5
fi
el "smoke ok: $(grep -o 'PSNR [0-9.]*' /tmp/smoke.log | tail -1)"
mkdir -p /tmp/parts
pids=""
for s in $scenes; do for v in $(python3 -c "import json; print(' '.join(json.load(open('$V'))))"); do
  sub=$(python3 -c "import json; print(json.dumps({'$v': json.load(open('$V'))['$v']}))")
  python3 -m gsgs_engine bench sparse --protocol $proto --scene $s --data-root /tmp/data --variants "$sub" --seeds 3 --work /tmp/work --doc /tmp/parts/${s}_$v.md > /tmp/parts/${s}_$v.log 2>&1 &
  pids="$pids $!"
done; done
while [ $(( $(date +%s) - t0 )) -lt $deadline ]; do
  alive=0; for p in $pids; do kill -0 $p 2>/dev/null && alive=1; done
  [ $alive = 0 ] && break; sleep 5
done
for p in $pids; do pkill -P $p 2>/dev/null; kill $p 2>/dev/null; done
el "grid stopped"; nvidia-smi --query-gpu=memory.used,utilization.gpu --format=csv
python3 -m gsgs_engine bench sparse --protocol $proto --data-root /tmp/data --variants $V --seeds 3 --work /tmp/work --doc $OUT/${proto}_gpu.md --report-only 2>&1 | tail -40
(cd /tmp/work && find . -name metrics.json -o -name bench_log.txt | tar -czf $OUT/${proto}_cells.tar.gz -T -)
tail -n 3 /tmp/parts/*.log > $OUT/${proto}_parts.txt
el "done"
