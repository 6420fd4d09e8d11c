cd /tmp
for i in 1 2 3 4 5 6; do
OMP_NUM_THREADS=2 PYTHONPATH=/work/main /work/main/.venv/bin/python - <<'PY'
import statistics, time, torch
from gsgs_engine.bench.machine_speed import *
from gsgs_engine.bench import machine_speed as M
from gsgs_engine.render import render
from gsgs_engine.bench.rasterizer import make_scene, SH_DEGREE
torch.set_num_threads(2)
tensors, camera = make_scene(M.PROBE_GAUSSIANS, M.PROBE_SIDE, seed=0)
leaves = [t.requires_grad_() for t in tensors]; bg = torch.ones(3)
def once():
    t0 = time.perf_counter(); out = render(*leaves, camera, SH_DEGREE, bg, backend="cpu")
    (out.color.sum() + out.alpha.sum()).backward()
    for l in leaves: l.grad = None
    return (time.perf_counter() - t0) * 1000
once()
ts = [once() for _ in range(31)]
print(f"med7 {statistics.median(ts[:7]):.1f} min7 {min(ts[:7]):.1f} med31 {statistics.median(ts):.1f} min31 {min(ts):.1f} lowq31 {sorted(ts)[7]:.1f}")
PY
done
