import json, glob, os, statistics as st, shutil, sys
base = {}
for f in glob.glob('/work/main/docs/runs/speed/s28/cells/*_auto_fused_seed*.metrics.json'):
    n = os.path.basename(f); scene = n.split('_auto')[0]; seed = int(n.split('seed')[1].split('.')[0])
    base[(scene, seed)] = json.load(open(f))
new = {}
for tag in ('abs2', 'abs3', 'abs4'):
    for f in glob.glob(f'/tmp/s29/w/{tag}/*/*/{tag}/seed*/result/metrics.json'):
        p = f.split('/'); scene = p[6]; seed = int(p[8][4:])
        new[(tag, scene, seed)] = json.load(open(f))
for tag in ('abs2', 'abs3', 'abs4'):
    for scene in ('blender_lego', 'blender_chair', 'llff_flower', 'llff_horns'):
        seeds = sorted(s for (t, sc, s) in new if t == tag and sc == scene)
        if not seeds: continue
        row = []
        for s in seeds:
            a = new[(tag, scene, s)]; b = base.get((scene, s))
            row.append(f"s{s} {b['psnr']:.2f}->{a['psnr']:.2f} ({a['psnr']-b['psnr']:+.2f}) lp {b['lpips']:.4f}->{a['lpips']:.4f} n {b['num_gaussians']}->{a['num_gaussians']}" if b else f"s{s} {a['psnr']:.2f}")
        print(tag, scene, '\n   ' + '\n   '.join(row))
def mean(tag, scenes, seeds, key):
    a = [new[(tag, sc, s)][key] for sc in scenes for s in seeds if (tag, sc, s) in new]
    b = [base[(sc, s)][key] for sc in scenes for s in seeds if (tag, sc, s) in new]
    return (st.mean(b), st.mean(a), len(a)) if a else None
for tag, scenes in (('abs3', ('blender_lego', 'blender_chair')), ('abs4', ('llff_flower', 'llff_horns'))):
    for seeds in ((0, 1, 2), (3, 4, 5), (0, 1, 2, 3, 4, 5)):
        for key in ('psnr', 'ssim', 'lpips'):
            m = mean(tag, scenes, seeds, key)
            if m: print(tag, seeds, key, f"{m[0]:.4f} -> {m[1]:.4f} ({m[2]} cells)")
if len(sys.argv) > 1:
    out = sys.argv[1]; os.makedirs(out, exist_ok=True)
    for (tag, scene, seed), d in new.items():
        shutil.copy(f'/tmp/s29/w/{tag}/{scene.split("_")[0]}/{scene}/{tag}/seed{seed}/result/metrics.json', f'{out}/{scene}_{tag}_seed{seed}.metrics.json')
