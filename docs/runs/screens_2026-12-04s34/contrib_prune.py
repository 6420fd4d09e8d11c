"""Session 34: post-hoc pruning of Gaussians that no training view draws (sum of blend weights over its pixels),
test PSNR before and after. usage: python contrib_prune.py DATA_DIR TRAIN_VIEWS PLY"""
import numpy as np, torch, sys
exec(open(__import__('os').path.join(__import__('os').path.dirname(__file__), 'common.py')).read())

def contributions(cam):
    col = torch.zeros(model.num_gaussians, 1, 3, requires_grad=True)
    out = render(model.means.detach(), model.quats.detach(), model.scales.detach(), model.opacities.detach(), col, cam,
                 sh_degree=0, background=bg, backend="cpu")
    out.color.sum().backward()
    return col.grad[:, 0, 0] / 0.28209479177387814  # SH DC basis: colour = C0 * dc + 0.5

with torch.no_grad():
    pass
contrib = torch.stack([contributions(v.camera) for v in scene.train])  # [views, N]
best = contrib.max(0).values
print("Gaussians", model.num_gaussians, "quantiles of max-view contribution (pixel weights):",
      [round(float(q), 4) for q in torch.quantile(best, torch.tensor([0.01, 0.05, 0.1, 0.25, 0.5]))])
def test_psnr(keep):
    vals = []
    for v in scene.test:
        truth = img(v)
        with torch.no_grad():
            o = render(model.means[keep], model.quats[keep], model.scales[keep], model.opacities[keep],
                       model.sh(deg)[keep], v.camera, sh_degree=deg, background=bg, backend="cpu")
        vals.append(float(10 * torch.log10(1 / ((o.color.clamp(0, 1) - truth) ** 2).mean())))
    return vals
base = test_psnr(torch.ones(model.num_gaussians, dtype=torch.bool))
print("all", round(np.mean(base), 3), [round(x, 2) for x in base])
for thr in [0.01, 0.1, 0.5, 1.0, 2.0]:
    keep = best >= thr
    r = test_psnr(keep)
    print(f"prune < {thr}: removed {int((~keep).sum())}", round(np.mean(r), 3), [round(x, 2) for x in r])
