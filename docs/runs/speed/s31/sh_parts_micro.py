# What the SH coefficients in two parts save a training render: the trained lego model (SH degree 2, 63.8k
# Gaussians) rendered at its 8 training views, forward + backward of a random colour loss, with the parameters as
# leaves the way the trainer holds them (sh_dc [N,1,3], sh_rest [N,8,3]); `joined` passes model.sh()'s
# concatenation (the build before), `parts` passes the two parameters (this build); alternating, N rounds of the
# 8 views each, 2 threads. python sh_parts_micro.py CELL_FOLDER N
import json, os, statistics, sys, time
from pathlib import Path
import torch
torch.set_num_threads(int(os.environ.get("NT", "2")))
from gsgs_engine.allocator import keep_freed_memory; keep_freed_memory()
from gsgs_engine.io.ply import read_gaussian_ply
from gsgs_engine.gaussians import GaussianModel
from gsgs_engine.io.loader import load_scene
from gsgs_engine.render import render

cell = Path(sys.argv[1]); rounds = int(sys.argv[2])
job = json.loads((cell / "job.json").read_text()); d = job["data"]; s = job["settings"]
scene = load_scene(d["path"], resolution_scale=s.get("resolution_scale"), **{k: v for k, v in d.items() if k != "path"})
model = GaussianModel.from_ply(read_gaussian_ply(cell / "result" / "point_cloud.ply"))
cams = [v.camera for v in scene.train]
degree = model.max_sh_degree
leaves = {k: model.params[k].detach().clone().requires_grad_(True) for k in ("means", "quats", "log_scales", "opacity_logits", "sh_dc", "sh_rest")}
weights = {}

def step(i, mode):
    for p in leaves.values(): p.grad = None
    cam = cams[i % len(cams)]
    t0 = time.perf_counter()
    scales, opac = torch.exp(leaves["log_scales"]), torch.sigmoid(leaves["opacity_logits"])
    if mode == "joined":
        sh = torch.cat([leaves["sh_dc"], leaves["sh_rest"][:, :(degree + 1) ** 2 - 1]], dim=1)
        out = render(leaves["means"], leaves["quats"], scales, opac, sh, cam, sh_degree=degree, background=torch.ones(3), backend="cpu")
    else:
        out = render(leaves["means"], leaves["quats"], scales, opac, leaves["sh_dc"], cam, sh_degree=degree, background=torch.ones(3),
                     backend="cpu", sh_rest=leaves["sh_rest"])
    k = i % len(cams)
    if k not in weights: weights[k] = torch.rand(out.color.shape, generator=torch.Generator().manual_seed(k))
    (out.color * weights[k]).sum().backward()
    return time.perf_counter() - t0

times = {"joined": [], "parts": []}
for i in range(len(cams)):
    step(i, "joined"); step(i, "parts")
for r in range(rounds):
    for mode in (("joined", "parts") if r % 2 == 0 else ("parts", "joined")):
        times[mode].append(sum(step(i, mode) for i in range(len(cams))) / len(cams))
j, p = statistics.median(times["joined"]), statistics.median(times["parts"])
print(f"{model.num_gaussians} Gaussians, degree {degree}, {rounds} rounds of {len(cams)} views, {torch.get_num_threads()} threads: "
      f"joined {1e3 * j:.2f} ms, parts {1e3 * p:.2f} ms a render (medians of the rounds' means); saved {1e3 * (j - p):.2f} ms "
      f"({100 * (j - p) / j:.1f} %); paired rounds: {sum(a > b for a, b in zip(times['joined'], times['parts']))} of {rounds} faster with parts")
