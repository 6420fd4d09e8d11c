import json, glob, sys, os
rows = []
for f in sorted(glob.glob('/tmp/s48/runs/llff/*/*/seed*/result/metrics.json') + glob.glob('/tmp/s48/runs/blender/*/*/seed*/result/metrics.json')):
    p = f.split('/'); m = json.load(open(f))
    print(f"{p[5]:14s} {p[6]:12s} {p[7]:6s} psnr {m['psnr']:.3f} ssim {m['ssim']:.3f} lpips {m['lpips']:.3f} train {m['train_seconds']:.0f}s init {m['init']['num_points']} G {m['num_gaussians']}  views " + " ".join(f"{v['psnr']:.2f}" for v in m['per_view']))
