import json,glob,sys
root=sys.argv[1] if len(sys.argv)>1 else '/tmp/s43/runs'
for f in sorted(glob.glob(root+'/*/*/*/seed*/result/metrics.json')):
    m=json.load(open(f)); p=f[len(root)+1:].split('/')
    print(f"{p[1]:14s} {p[2]:10s} {p[3]:6s} psnr {m['psnr']:.3f} ssim {m['ssim']:.3f} lpips {m['lpips_vgg']:.3f} train {m['train_seconds']:.1f} it {m['iterations']} n {m['num_gaussians']}")
