# the binocular term's torch form against the compiled one on a trained flower model's real renders
# usage: python realgrad.py CELL_FOLDER SHIFT_SCALE BASELINE (a trained protocol cell; session 28: the flower cell, 0.5, 2.0)
import sys, json, torch
sys.path.insert(0, '/work/main')
from pathlib import Path
from gsgs_engine.io.ply import read_gaussian_ply
from gsgs_engine.gaussians import GaussianModel
from gsgs_engine.io.loader import load_scene
from gsgs_engine.render import render
from gsgs_engine.train.techniques.binocular import warp_shifted_to_view, masked_l1, shifted_camera, surface_depth, MIN_OPAQUE
from gsgs_engine.train.fused_binocular import binocular_l1
torch.set_num_threads(1)
cell = Path(sys.argv[1]); scale = float(sys.argv[2])
job = json.loads((cell / "job.json").read_text()); d = job["data"]; s = job["settings"]
scene = load_scene(d["path"], resolution_scale=s.get("resolution_scale") or 1.0, **{k: v for k, v in d.items() if k != "path"})
model = GaussianModel.from_ply(read_gaussian_ply(cell / "result" / "point_cloud.ply"))
bg = torch.tensor(s.get("background") or [0.0, 0.0, 0.0], dtype=torch.float32) if s.get("background") else torch.zeros(3)
for vi, v in enumerate(scene.train[:3]):
    target = torch.as_tensor(v.image(), dtype=torch.float32)[..., :3]
    for b in (float(sys.argv[3]), -float(sys.argv[3])):
        res = {}
        for name in ('torch', 'fused'):
            params = [p.detach().clone().requires_grad_(True) for p in (model.means, model.quats, model.scales, model.opacities, model.sh(0))]
            out = render(*params, v.camera, sh_degree=0, background=bg, backend="cpu")
            sh_cam = shifted_camera(v.camera, b)
            if scale != 1: sh_cam = sh_cam.scaled(scale)
            out2 = render(*params, sh_cam, sh_degree=0, background=bg, backend="cpu")
            z = surface_depth(out.depth, out.alpha)
            if name == 'torch':
                warped, valid = warp_shifted_to_view(v.camera, z, sh_cam, out2.color)
                mask = valid & (out.alpha.detach() > MIN_OPAQUE); l = masked_l1(warped, target, mask)
            else:
                l, mask = binocular_l1(v.camera, z, sh_cam, out2.color, target, out.alpha, MIN_OPAQUE)
            l.backward()
            res[name] = (float(l), mask, [p.grad.clone() for p in params])
        a, f = res['torch'], res['fused']
        line = f"view {vi} b {b:+.2f}: loss {a[0]:.7f} {f[0]:.7f} mask diff {(a[1]!=f[1]).sum().item()}/{a[1].sum().item()} |"
        for n, ga, gf in zip(('means','quats','scales','opac','sh'), a[2], f[2]):
            dd = (ga - gf)
            line += f" {n}: rel {float(dd.abs().max()/ga.abs().max()):.1e} dot {float((ga*gf).sum()/(ga*ga).sum()):.6f}"
        print(line, flush=True)
