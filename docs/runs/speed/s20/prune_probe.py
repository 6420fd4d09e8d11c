import json, sys, time, math, torch
from gsgs_engine.gaussians import GaussianModel
from gsgs_engine.io import load_scene
from gsgs_engine.io.ply import read_gaussian_ply
from gsgs_engine.io.world_scale import ply_to_internal
from gsgs_engine.train.trainer import render_model
from gsgs_engine.render import cpu_backend
torch.set_num_threads(2)
job = sys.argv[1]
m = json.load(open(f"{job}/result/metrics.json"))
plan = m["plan"]
bg = tuple(plan["background"])
scene = load_scene(plan["data"], resolution_scale=plan["resolution_scale"], background=bg, train_ids=plan["train_ids"])
model0 = GaussianModel.from_ply(ply_to_internal(read_gaussian_ply(f"{job}/result/point_cloud.ply"), scene.world_scale))
bgt = torch.tensor(bg)
train = scene.split("train"); test = scene.split("test")
print(len(train), len(test), model0.num_gaussians)
# score: sum over training views of blending weight (unit colour gradient on one channel -> grad of the DC colour)
def score(model):
    s = torch.zeros(model.num_gaussians)
    for v in train:
        dc = model.params["sh_dc"]; dc.requires_grad_(True)
        out = render_model(model, v.camera, bgt, "cpu")
        out.color[..., 0].sum().backward()
        g = dc.grad.reshape(len(s), -1)[:, 0].abs(); s += g
        dc.grad = None
    dc.requires_grad_(False)
    return s
def psnr_of(model, views):
    ps = []; t0 = time.perf_counter()
    with torch.no_grad():
        for v in views:
            out = render_model(model, v.camera, bgt, "cpu")
            gt = torch.from_numpy(v.image())
            mse = ((out.color.clamp(0,1) - gt) ** 2).mean().item()
            ps.append(-10 * math.log10(mse))
    return sum(ps) / len(ps), (time.perf_counter() - t0) / len(views)
import os
sc = score(model0) if not os.environ.get("BYOPA") else model0.opacities.detach().reshape(-1)
print("score pct", [float(x) for x in torch.quantile(sc, torch.tensor([0.1, 0.3, 0.5, 0.7, 0.9]))])
base = psnr_of(model0, test); print("full", model0.num_gaussians, base, "train", psnr_of(model0, train)[0])
order = torch.argsort(sc)
for frac in (0.05, 0.1, 0.2, 0.3):
    keep = torch.ones(model0.num_gaussians, dtype=torch.bool); keep[order[: int(frac * len(order))]] = False
    st = model0.state_dict(); st["params"] = {k: v[keep] for k, v in st["params"].items()}
    mk = GaussianModel.from_state_dict(st)
    print("prune", frac, mk.num_gaussians, psnr_of(mk, test), "train", psnr_of(mk, train)[0], flush=True)
