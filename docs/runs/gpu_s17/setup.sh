#!/bin/bash
# device call 1: pycolmap + gsplat site, LLFF data, gsplat's CUDA build started in the background
t0=$(date +%s); el() { echo "[$(( $(date +%s) - t0 )) s] $*"; }
mkdir -p /tmp/site /tmp/data && tar -xJf .dev/siteA.tar.xz -C /tmp/site || exit 3
el "siteA unpacked"
python3 - <<'PY'
import cv2, os, shutil, numpy as np
for scene in os.listdir(".dev/llff"):
    d = f"/tmp/data/{scene}"; os.makedirs(f"{d}/images_8", exist_ok=True)
    shutil.copy(f".dev/llff/{scene}/poses_bounds.npy", d)
    for f in os.listdir(f".dev/llff/{scene}/images_8"):
        im = cv2.imdecode(np.fromfile(f".dev/llff/{scene}/images_8/{f}", np.uint8), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(f"{d}/images_8/{f[:-5]}", im)
print({s: len(os.listdir(f"/tmp/data/{s}/images_8")) for s in os.listdir("/tmp/data")})
PY
el "llff decoded"
cat > /tmp/build_gsplat.sh <<'B'
cd /tmp && export PYTHONPATH=/tmp/site MAX_JOBS=16 TORCH_CUDA_ARCH_LIST=9.0
python3 -c "from gsplat.cuda._backend import _C; print('gsplat kernels', _C is not None)" > /tmp/build.log 2>&1
echo "BUILD_DONE rc=$?" >> /tmp/build.log
B
setsid nohup bash /tmp/build_gsplat.sh > /dev/null 2>&1 < /dev/null &
nvidia-smi -L; nproc; free -g | head -2
PYTHONPATH=/tmp/site python3 -c "import torch, numpy, cv2, pycolmap; print(torch.__version__, torch.cuda.is_available(), numpy.__version__, cv2.__version__, pycolmap.__version__)"
PYTHONPATH=/tmp/site:$PWD python3 -c "import gsgs_engine.bench.sparse, gsgs_engine.train.trainer; print('engine imports')"
sleep 2; cat /tmp/build.log; el "setup done"
