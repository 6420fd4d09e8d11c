# python render_grads_dump.py BUILD OUT CELL...: renders (and gradients) of each trained cell's first two training views and first test view; SCALE=0.5 renders at another image scale than the job's.
import sys, json, torch
sys.path.insert(0, sys.argv[1])
from pathlib import Path
from gsgs_engine.io.ply import read_gaussian_ply
from gsgs_engine.gaussians import GaussianModel
from gsgs_engine.io.loader import load_scene
from gsgs_engine.render import render
torch.set_num_threads(2)
res = {}
for cell in sys.argv[3:]:
    cell = Path(cell)
    job = json.loads((cell / "job.json").read_text()); d = job["data"]; s = job["settings"]
    scene = load_scene(d["path"], resolution_scale=float(__import__("os").environ.get("SCALE", s.get("resolution_scale") or 1.0)), **{k: v for k, v in d.items() if k != "path"})
    model = GaussianModel.from_ply(read_gaussian_ply(cell / "result" / "point_cloud.ply"))
    for i, v in enumerate(scene.train[:2] + scene.test[:1]):
        params = [p.detach().clone().requires_grad_(True) for p in (model.means, model.quats, model.scales, model.opacities, model.sh(0))]
        out = render(*params, v.camera, sh_degree=0, background=torch.ones(3), backend="cpu")
        w = torch.rand(out.color.shape, generator=torch.Generator().manual_seed(i))
        (((out.color * w).sum() + out.depth.mean() + out.alpha.sum()) if i % 2 == 0 else (out.color * w).sum()).backward()
        res[f"{cell.parts[-3]}_{i}"] = [out.color.detach(), out.depth.detach(), out.alpha.detach()] + [p.grad for p in params]
torch.save(res, sys.argv[2])
