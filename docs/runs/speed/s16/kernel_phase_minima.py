# per-render kernel phase times (fwd+bwd of colour), min and median over N renders, 1 thread (NT=k: k threads)
import sys, json, torch, statistics
sys.path.insert(0, sys.argv[1])
from pathlib import Path
import os; torch.set_num_threads(int(os.environ.get("NT", "1")))
from gsgs_engine.allocator import keep_freed_memory; keep_freed_memory()
from gsgs_engine.io.ply import read_gaussian_ply
from gsgs_engine.gaussians import GaussianModel
from gsgs_engine.io.loader import load_scene
from gsgs_engine.render import render
from gsgs_engine.render import cpu_backend as cb
res = []
for cell in sys.argv[3:]:
    cell = Path(cell)
    job = json.loads((cell / "job.json").read_text()); d = job["data"]; s = job["settings"]
    scene = load_scene(d["path"], resolution_scale=s.get("resolution_scale"), **{k: v for k, v in d.items() if k != "path"})
    model = GaussianModel.from_ply(read_gaussian_ply(cell / "result" / "point_cloud.ply"))
    cams = [v.camera for v in scene.train]
    params = [p.detach().clone().requires_grad_(True) for p in (model.means, model.quats, model.scales, model.opacities, model.sh(0))]
    ws = {}
    def fb(i):
        for p in params: p.grad = None
        out = render(*params, cams[i % len(cams)], sh_degree=0, background=torch.ones(3), backend="cpu")
        k = i % len(cams)
        if k not in ws: ws[k] = torch.rand(out.color.shape, generator=torch.Generator().manual_seed(k))
        (out.color * ws[k]).sum().backward()
    for i in range(len(cams)): fb(i)
    rec = {'binning': [], 'raster_forward': [], 'raster_backward': []}
    for i in range(int(sys.argv[2])):
        p0 = cb.phase_seconds(); fb(i); p1 = cb.phase_seconds()
        for k in rec: rec[k].append(1e3 * (p1[k] - p0[k]))
    # per camera min (different views differ), summed over cameras
    nc = len(cams)
    parts = []
    for k, v in rec.items():
        mins = [min(v[c::nc]) for c in range(nc)]
        parts.append(f"{k[:8]} {sum(mins)/nc:6.2f}")
    res.append(f"{cell.parts[-3][:6]} " + " ".join(parts))
print(' | '.join(res))
