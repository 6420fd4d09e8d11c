"""Time forward+backward of a trained model's renders at the test views; PSNR of the renders. usage: tmin.py PLY DATA [ROUNDS]"""
import sys, time, torch, numpy as np
from gsgs_engine.gaussians import GaussianModel
from gsgs_engine.io import load_scene
from gsgs_engine.io.ply import read_gaussian_ply
from gsgs_engine.io.world_scale import ply_to_internal
from gsgs_engine.train.trainer import render_model
torch.set_num_threads(2)
ply, data = sys.argv[1], sys.argv[2]; rounds = int(sys.argv[3]) if len(sys.argv) > 3 else 3
scene = load_scene(data, resolution_scale=0.5, background=(1.0, 1.0, 1.0))
views = scene.split("test")[:12]
model = GaussianModel.from_ply(ply_to_internal(read_gaussian_ply(ply), scene.world_scale))
bg = torch.ones(3)
best = []
gts = {v.name: torch.from_numpy(np.ascontiguousarray(v.image())).float() for v in views}
for r in range(rounds):
    t0 = time.perf_counter(); ps = []
    for v in views:
        out = render_model(model, v.camera, bg, "cpu")
        gt = gts[v.name]
        loss = (out.color - gt).abs().mean(); loss.backward()
        ps.append(float(-10 * torch.log10(((out.color.detach().clamp(0, 1) - gt) ** 2).mean())))
        for p in model.params.values(): p.grad = None
    best.append((time.perf_counter() - t0) / len(views) * 1000)
print(f"{sys.argv[1].split('/runs/')[-1][:60]} ms/render {' '.join(f'{b:.1f}' for b in best)} psnr {np.mean(ps):.3f}")
