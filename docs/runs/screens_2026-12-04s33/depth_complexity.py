"""Per-pixel depth complexity of a trained cell's model at a training view: entries visited, blended
(alpha >= 1/255 before termination), and how many would remain under looser termination thresholds."""
import sys, json, torch, numpy as np
from pathlib import Path
torch.set_num_threads(2)
from gsgs_engine.io.ply import read_gaussian_ply
from gsgs_engine.gaussians import GaussianModel
from gsgs_engine.io.loader import load_scene
from gsgs_engine.render import render
from gsgs_engine.render import cpu_backend as cb
from gsgs_engine.render.reference import bin_gaussians
cap = {}
orig = cb.rasterize_cpu
def grab(means2d, conics, colors, opacities, depths, radii, width, height, background, **kw):
    cap.update(m=means2d.detach().clone(), c=conics.detach().clone(), o=opacities.detach().clone().reshape(-1), r=radii.detach().clone(), d=depths.detach().clone(), W=width, H=height)
    return orig(means2d, conics, colors, opacities, depths, radii, width, height, background, **kw)
cb.rasterize_cpu = grab
cell = Path(sys.argv[1]); view = int(sys.argv[2]) if len(sys.argv) > 2 else 0
job = json.loads((cell / "job.json").read_text()); d = job["data"]; s = job["settings"]
scene = load_scene(d["path"], resolution_scale=s.get("resolution_scale"), **{k: v for k, v in d.items() if k != "path"})
model = GaussianModel.from_ply(read_gaussian_ply(cell / "result" / "point_cloud.ply"))
cam = scene.train[view].camera
with torch.no_grad():
    render(model.means, model.quats, model.scales, model.opacities, model.sh(0), cam, sh_degree=0, background=torch.ones(3), backend="cpu")
o_all = model.opacities.detach().reshape(-1)
print("gaussians", o_all.numel(), "opacity quantiles 10/50/90:", [round(float(x), 3) for x in torch.quantile(o_all, torch.tensor([0.1, 0.5, 0.9]))])
m, c, o, r, dep, W, H = cap['m'], cap['c'], cap['o'], cap['r'], cap['d'].reshape(-1), cap['W'], cap['H']
rr = r.reshape(r.shape[0], -1)[:, 0]
ids, starts, counts = bin_gaussians(m, r, dep, W, H)
T = 16; ntx = (W + T - 1) // T
ys, xs = torch.meshgrid(torch.arange(T), torch.arange(T), indexing="ij")
thr = [1e-4, 3e-4, 1e-3, 3e-3, 1e-2]
visited = torch.zeros(H, W); blended = torch.zeros(H, W); blended_at = {t: torch.zeros(H, W) for t in thr}
color_err = {t: 0.0 for t in thr}
for tile in range(counts.numel()):
    n = int(counts[tile]);
    if n == 0: continue
    g = ids[starts[tile]:starts[tile] + n]
    tx, ty = tile % ntx, tile // ntx
    px = (tx * T + xs).reshape(-1).float() + 0.5; py = (ty * T + ys).reshape(-1).float() + 0.5
    keep = (px < W) & (py < H)
    dx = m[g, 0][None] - px[:, None]; dy = m[g, 1][None] - py[:, None]
    A, B, C = c[g, 0][None], c[g, 1][None], c[g, 2][None]
    pw = -0.5 * (A * dx * dx + C * dy * dy) - B * dx * dy
    a = (o[g][None] * torch.exp(pw.clamp(max=0))).clamp(max=0.99)
    used = (pw <= 0) & (a >= 1 / 255)
    a = torch.where(used, a, torch.zeros_like(a))
    Tafter = torch.cumprod(1 - a, -1)
    for t in thr:
        stop = used & (Tafter < t)
        first = torch.where(stop.any(-1), stop.float().argmax(-1), torch.full((a.shape[0],), n))
        inc = torch.arange(n)[None] < first[:, None]
        bl = (used & inc).sum(-1).float()
        vis = first.clamp(max=n - 1).float() + 1
        yy = (ty * T + ys).reshape(-1)[keep]; xx = (tx * T + xs).reshape(-1)[keep]
        blended_at[t][yy, xx] = bl[keep]
        if t == 1e-4:
            visited[yy, xx] = vis[keep]
print(f"{W}x{H} view {view}: visited per pixel mean {visited.mean():.1f}; blended per pixel at T_min:")
for t in thr:
    print(f"  T_min {t:g}: blended mean {blended_at[t].mean():.2f}  (x{float(blended_at[t].sum() / blended_at[1e-4].sum()):.3f} of 1e-4)")
print("pixels with >0 blended:", float((blended_at[1e-4] > 0).float().mean()))
