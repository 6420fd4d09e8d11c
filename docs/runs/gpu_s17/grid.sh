#!/bin/bash
# device call 2: cv2-contrib site, Blender data, then: the recipe (--prior auto, CUDA) alone at 1000 steps on
# flower and lego (seconds), then seed 0 of all four protocol scenes at 1000 / 3000 / 10000 steps side by side.
# usage: bash .dev/grid.sh DEADLINE_S
deadline=$1; export PY=${PY:-python3}
t0=$(date +%s); el() { echo "[$(( $(date +%s) - t0 )) s] $*"; }
export PYTHONUNBUFFERED=1 OMP_WAIT_POLICY=PASSIVE
mkdir -p /tmp/siteB && tar -xJf .dev/siteB.tar.xz -C /tmp/siteB || exit 3
export PYTHONPATH=/tmp/siteB:/tmp/site:$PWD
$PY - <<'PY'
import cv2, os, shutil, numpy as np
src = ".dev/blender"
for root, dirs, files in os.walk(src):
    rel = os.path.relpath(root, src); os.makedirs(f"/tmp/data/{rel}", exist_ok=True)
    for f in files:
        if f.endswith(".a.webp"):
            continue
        if f.endswith(".rgb.webp"):
            base = f[:-len(".rgb.webp")]
            rgb = cv2.imdecode(np.fromfile(f"{root}/{f}", np.uint8), cv2.IMREAD_UNCHANGED)
            a = cv2.imdecode(np.fromfile(f"{root}/{base}.a.webp", np.uint8), cv2.IMREAD_UNCHANGED)
            a = a[..., 0] if a.ndim == 3 else a
            cv2.imwrite(f"/tmp/data/{rel}/{base}", np.dstack([rgb, a]))
        else:
            shutil.copy(f"{root}/{f}", f"/tmp/data/{rel}/{f}")
print(sorted(os.listdir("/tmp/data")))
PY
el "data ready"
for i in $(seq 1 120); do grep -q BUILD_DONE /tmp/build.log 2>/dev/null && break; sleep 1; done
cat /tmp/build.log; el "gsplat build waited"
$PY -c "import torch, pycolmap, gsplat, numpy, cv2; print(torch.__version__, pycolmap.__version__, gsplat.__version__, numpy.__version__, cv2.__version__, cv2.ximgproc is not None)" || exit 4
V="{\"auto\": {\"prior\": \"auto\", \"backend\": \"${BACKEND:-cuda}\"}}"
cell() {  # proto scene iters seed threads
  OMP_NUM_THREADS=$5 $PY -m gsgs_engine bench sparse --protocol $1 --scene $2 --data-root /tmp/data --variants "$V" \
    --seeds $4-$4 --iters $3 --work /tmp/work/it$3 --doc /tmp/parts/$2_it$3_s$4.md > /tmp/parts/$2_it$3_s$4.log 2>&1
}
mkdir -p /tmp/parts
# alone: one cell at a time, nothing else on the machine
for pc in llff:llff_flower blender:blender_lego; do
  cell ${pc%%:*} ${pc#*:} 1000 0 4; el "alone ${pc#*:} 1000: rc=$? $(grep -o 'PSNR [0-9.]*' /tmp/parts/${pc#*:}_it1000_s0.log | tail -1)"
  tail -3 /tmp/parts/${pc#*:}_it1000_s0.log
done
# side by side: seed 0 of the four scenes at 3000 and 10000 steps, and 1000 steps for horns and chair
pids=""
for pc in llff:llff_flower llff:llff_horns blender:blender_lego blender:blender_chair; do
  its=3000; case $pc in *flower|*lego) its="10000 3000";; esac
  for it in $its; do setsid bash -c "$(declare -f cell); V='$V'; cell ${pc%%:*} ${pc#*:} $it 0 1" & pids="$pids $!"; done
done
for pc in llff:llff_horns blender:blender_chair; do setsid bash -c "$(declare -f cell); V='$V'; cell ${pc%%:*} ${pc#*:} 1000 0 1" & pids="$pids $!"; done
while [ $(( $(date +%s) - t0 )) -lt $deadline ]; do
  alive=0; for p in $pids; do kill -0 $p 2>/dev/null && alive=1; done
  [ $alive = 0 ] && break; sleep 3
done
el "grid stopped"; nvidia-smi --query-gpu=memory.used,utilization.gpu --format=csv
for p in $pids; do kill -- -$p 2>/dev/null; done
for it in 1000 3000 10000; do for proto in llff blender; do
  $PY -m gsgs_engine bench sparse --protocol $proto --data-root /tmp/data --variants "$V" --seeds 1 --iters $it \
    --work /tmp/work/it$it --doc /tmp/work/report_${proto}_it$it.md --report-only > /dev/null 2>&1
done; done
(cd /tmp/work && find . -name metrics.json -o -name bench_log.txt -o -name status.json -o -name 'report_*' | tar -czf $OUT/cells.tar.gz -T -)
tar -czf $OUT/parts.tar.gz -C /tmp parts
(cd /tmp/parts && for f in *.log; do echo "== $f"; tail -n 3 $f; done); cat /tmp/work/report_*.md | grep -E '^\| (llff|blender)_' 
ls $OUT; el "done"
