import sys, json, torch, numpy as np
from pathlib import Path
torch.set_num_threads(2)
from gsgs_engine.io.ply import read_gaussian_ply
from gsgs_engine.gaussians import GaussianModel
from gsgs_engine.io.loader import load_scene
from gsgs_engine.render import render
from gsgs_engine.render import cpu_backend as cb
cap = {}
orig = cb.rasterize_cpu
def grab(means2d, conics, colors, opacities, depths, radii, width, height, background):
    cap.update(m=means2d.detach().numpy().copy(), c=conics.detach().numpy().copy(), o=opacities.detach().numpy().copy(), r=radii.detach().numpy().copy(), W=width, H=height)
    return orig(means2d, conics, colors, opacities, depths, radii, width, height, background)
cb.rasterize_cpu = grab
import gsgs_engine.render as R
for name in dir(R):
    pass
cell = Path(sys.argv[1])
job = json.loads((cell / "job.json").read_text()); d = job["data"]; s = job["settings"]
scene = load_scene(d["path"], resolution_scale=s.get("resolution_scale"), **{k: v for k, v in d.items() if k != "path"})
model = GaussianModel.from_ply(read_gaussian_ply(cell / "result" / "point_cloud.ply"))
cam = scene.train[0].camera
with torch.no_grad():
    out = render(model.means, model.quats, model.scales, model.opacities, model.sh(0), cam, sh_degree=0, background=torch.ones(3), backend="cpu")
print({k: (v.shape if hasattr(v,'shape') else v) for k,v in cap.items()})
m, c, o, r, W, H = cap['m'], cap['c'], cap['o'].reshape(-1), cap['r'], cap['W'], cap['H']
vis = (r.reshape(r.shape[0], -1)[:, 0] > 0) & (o >= 1/255)
m, c, o = m[vis], c[vis], o[vis]
A, B, C = c[:,0], c[:,1], c[:,2]
lo = np.log(o.astype(np.float64))
det = A.astype(np.float64)*C - B.astype(np.float64)**2
k = np.maximum(0, 2*(np.log(255)+lo))/det
ex = np.sqrt(C*k)*1.001+1; ey = np.sqrt(A*k)*1.001+1
floor = (np.log(1/255) - lo) - 1e-3
T=16
tx0 = np.clip(np.floor((m[:,0]-ex)/T),0,(W+T-1)//T-1).astype(int); tx1=np.clip(np.floor((m[:,0]+ex)/T),0,(W+T-1)//T-1).astype(int)
ty0 = np.clip(np.floor((m[:,1]-ey)/T),0,(H+T-1)//T-1).astype(int); ty1=np.clip(np.floor((m[:,1]+ey)/T),0,(H+T-1)//T-1).astype(int)
ent = []
for g in range(len(m)):
    for ty in range(ty0[g], ty1[g]+1):
        for tx in range(tx0[g], tx1[g]+1):
            ent.append((g, tx, ty))
ent = np.array(ent)
print("gaussians", len(m), "entries (box)", len(ent))
g = ent[:,0]; px0 = ent[:,1]*T; py0 = ent[:,2]*T
ys, xs = np.mgrid[0:T, 0:T]
tot = {}
for s0 in range(0, len(ent), 20000):
    sl = slice(s0, s0+20000)
    gg = g[sl]
    X = px0[sl,None,None] + xs + 0.5; Y = py0[sl,None,None] + ys + 0.5
    dx = m[gg,0,None,None] - X; dy = m[gg,1,None,None] - Y
    pw = -0.5*(A[gg,None,None]*dx*dx + C[gg,None,None]*dy*dy) - B[gg,None,None]*dx*dy
    inimg = (X < W) & (Y < H)
    full = (pw >= floor[gg,None,None]) & inimg & (pw <= 0)
    inx = np.abs(dx) <= ex[gg,None,None]; iny = np.abs(dy) <= ey[gg,None,None]
    inbox = inx & iny & inimg
    n = full.shape[0]
    # 8x1
    f8 = full.reshape(n, 16, 2, 8).any(-1); 
    rowin = iny[:, :, 0]  # n,16
    colin = inx[:, 0, :].reshape(n, 2, 8).any(-1)  # n,2
    v8 = rowin[:, :, None] & colin[:, None, :]
    # 4x2
    f42 = full.reshape(n, 8, 2, 4, 4).any(axis=(2, 4))
    rowin2 = iny[:, :, 0].reshape(n, 8, 2).any(-1); colin2 = inx[:, 0, :].reshape(n, 4, 4).any(-1)
    v42 = rowin2[:, :, None] & colin2[:, None, :]
    lanes8 = full.reshape(n,16,2,8).sum(-1)[f8].sum(); lanes42 = full.reshape(n,8,2,4,4).sum(axis=(2,4))[f42].sum()
    for kk, vv in (('full8', f8.sum()), ('visit8', v8.sum()), ('full42', f42.sum()), ('visit42', v42.sum()), ('lanes', full.sum()), ('empty_entries', (~full.any(axis=(1,2))).sum())):
        tot[kk] = tot.get(kk, 0) + int(vv)
print(tot)
print("full steps 4x2 / 8x1: %.3f ; visited %.3f ; lane util 8x1 %.2f 4x2 %.2f" % (tot['full42']/tot['full8'], tot['visit42']/tot['visit8'], tot['lanes']/8/tot['full8'], tot['lanes']/8/tot['full42']))
